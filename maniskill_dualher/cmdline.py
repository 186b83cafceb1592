"""Command-line plumbing shared by train, sweep, report and evaluate: bad input answers with one line on
stderr and exit code 2. Imports nothing of the project, so every layer may use it."""
from __future__ import annotations

import argparse
import sys


class OneLineParser(argparse.ArgumentParser):
    """argparse that answers bad input with one line on stderr and exit code 2 (no 40-line usage)."""

    def error(self, message):  # noqa: D401
        self.exit(2, f"error: {message} (see --help)\n")

    def parse_args(self, args=None, namespace=None):
        return super().parse_args(_glue_negative_values(self, sys.argv[1:] if args is None else list(args)),
                                  namespace)


def _glue_negative_values(parser: argparse.ArgumentParser, argv):
    """``--ratio -0.2/1.2`` -> ``--ratio=-0.2/1.2``: argparse takes a value starting with '-' for a flag
    unless it is a plain negative number; glue it to its flag so validation can name the bad value."""
    takes_value = {o for a in parser._actions if a.nargs is None and a.option_strings
                   and not isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction,
                                          argparse.BooleanOptionalAction))
                   for o in a.option_strings}
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a in takes_value and i + 1 < len(argv) and len(argv[i + 1]) > 1 and argv[i + 1][0] == "-" \
                and (argv[i + 1][1].isdigit() or argv[i + 1][1] == "."):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out



def missing_package(module: str, purpose: str):
    """None if ``module`` imports, else one line saying what to install: ``purpose`` (e.g. "report draws its
    figures with") + the requirement as pyproject.toml states it (a dependency a broken install lacks)."""
    import importlib
    try:
        importlib.import_module(module)
        return None
    except ImportError:
        pass
    req = module
    try:
        from importlib.metadata import requires
        import re
        req = next((r for r in requires("maniskill_dualher") or () if ";" not in r  # not an extra's
                    and re.split(r"[<>=!~\[ ]", r, 1)[0].lower() == module.lower()), module)
    except Exception:  # noqa: BLE001  (not installed as a package: a source checkout)
        pass
    return f"{purpose} {module}, which is not installed here: pip install '{req}' (a dependency of maniskill_dualher)"
