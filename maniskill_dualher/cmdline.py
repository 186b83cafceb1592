"""Command-line plumbing shared by train, sweep, report and evaluate: bad input answers with one line on
stderr and exit code 2, an unknown choice or flag with "did you mean ...", an old spelling of a flag with the
new one. Imports nothing of the project, so every layer may use it."""
from __future__ import annotations

import argparse
import difflib
import sys
from typing import Iterable


def closest(word: str, choices: Iterable[str], cutoff: float = 0.6):
    """The closest of ``choices`` to ``word`` (difflib), or None."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=cutoff)
    return close[0] if close else None


def did_you_mean(word: str, choices: Iterable[str]) -> str:
    """' (did you mean X?)' for the closest of ``choices`` to ``word`` (difflib), else ''."""
    close = closest(word, choices)
    return f" (did you mean {close}?)" if close else ""


class _OldFlag(argparse.Action):
    """A flag's old spelling: refused with one line naming the new one (exit 2)."""

    def __init__(self, option_strings, dest, hint=None, **kw):
        kw.update(nargs="?", help=argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kw)
        self.hint = hint

    def __call__(self, parser, namespace, values, option_string=None):
        parser.error(f"{option_string} is not a flag here: {self.hint}")


def old_flag(parser: argparse.ArgumentParser, flag: str, hint: str) -> None:
    """Refuse ``flag`` (an old or another command's spelling) with ``hint``, e.g. "use --total-steps N"."""
    parser.add_argument(flag, dest=f"_old_{flag.lstrip('-').replace('-', '_')}", action=_OldFlag, hint=hint,
                        default=argparse.SUPPRESS)


class OneLineParser(argparse.ArgumentParser):
    """argparse that answers bad input with one line on stderr and exit code 2 (no 40-line usage)."""

    def error(self, message):  # noqa: D401
        self.exit(2, f"error: {message} (see --help)\n")

    def parse_args(self, args=None, namespace=None):
        args, extra = self.parse_known_args(_glue_negative_values(self, sys.argv[1:] if args is None else list(args)),
                                            namespace)
        if extra:
            flag = next((a.split("=", 1)[0] for a in extra if a.startswith("--")), None)
            flags = [o for a in self._actions if a.help != argparse.SUPPRESS for o in a.option_strings]
            self.error(f"unrecognized arguments: {' '.join(extra)}" + (did_you_mean(flag, flags) if flag else ""))
        return args

    def _check_value(self, action, value):  # an unknown choice: the choices and the closest one
        if action.choices is not None and value not in action.choices:
            choices = ", ".join(map(repr, action.choices))
            raise argparse.ArgumentError(action, f"invalid choice: {value!r} (choose from {choices})"
                                         + did_you_mean(value, action.choices))


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
