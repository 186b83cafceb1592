"""One parser for dotted config overrides: presets, arms, ``sweep --set`` and ``train --set`` all use it.

    sac.lr=3e-4                  every run (or, in an arm, every stage of a chain)
    adapt.sac.random_steps=0     only a chain's last (adaptation) stage; scratch's single stage too
    source.replay.her_k=4        every stage but the last
    stage1.sac.lr=1e-4           stage 1 of a chain
    replay.ratio=1/0             typed from the RunConfig field's annotation: ratios as a/b, tuples as 64,64

The type of a value comes from the field's annotation in ``config.py``, and the doc of a key is the
field's comment there, so adding a setting to ``RunConfig`` makes it settable everywhere at once.
"""
from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import dataclass
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

from ..cmdline import closest
from ..config import ConfigError, ReplayConfig, RunConfig, SACConfig, field_docs, format_ratio, parse_ratio

SECTIONS = {"sac": SACConfig, "replay": ReplayConfig}
STAGE_WORDS = ("adapt", "source")   # plus stage0, stage1, ...


@dataclass(frozen=True)
class Override:
    path: str                   # dotted RunConfig key, e.g. "sac.lr"
    value: Any                  # typed
    stage: Optional[str] = None  # None (all), "adapt", "source" or "stage<i>"

    def text(self) -> str:
        return (f"{self.stage}." if self.stage else "") + f"{self.path}={format_value(self.value)}"

    def applies_to(self, stage: Optional[int], n_stages: int) -> bool:
        """Does it apply to stage ``stage`` of an ``n_stages`` chain (None: a single-task run)?"""
        if self.stage is None:
            return True
        if stage is None:
            return False
        if self.stage == "adapt":
            return stage == n_stages - 1
        if self.stage == "source":
            return stage < n_stages - 1
        return self.stage == f"stage{stage}"


def format_value(v: Any) -> str:
    if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, float) for x in v):
        return format_ratio(v)
    if isinstance(v, tuple):
        return ",".join(map(str, v))
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


@functools.lru_cache(maxsize=None)
def _fields(cls) -> Dict[str, Tuple[Any, Any]]:
    # cached: get_type_hints compiles every string annotation again on each call, and a sweep's plan parses
    # ~250k overrides (measured: 170 of the 262 s of tests/test_recipes.py's planning went there)
    hints = typing.get_type_hints(cls)
    return {f.name: (hints[f.name], f) for f in dataclasses.fields(cls)}


def keys() -> Dict[str, str]:
    """Every settable dotted key -> its doc (the field's comment in config.py)."""
    out = {}
    for prefix, cls in [("", RunConfig)] + [(f"{k}.", c) for k, c in SECTIONS.items()]:
        docs = field_docs(cls)
        for name in _fields(cls):
            if name not in SECTIONS:
                out[prefix + name] = docs.get(name, "")
    return out


def _resolve(path: str):
    """'sac.lr' -> (annotation, field name, section or None); ConfigError for an unknown key."""
    parts = path.split(".")
    if len(parts) == 2 and parts[0] in SECTIONS:
        cls, name, section = SECTIONS[parts[0]], parts[1], parts[0]
    elif len(parts) == 1:
        cls, name, section = RunConfig, parts[0], None
    else:
        cls, name, section = None, None, None
    fields = _fields(cls) if cls else {}
    if name not in fields or name in SECTIONS:
        close = [k for k in keys() if k.split(".")[-1] == parts[-1]]  # the right name in the wrong section
        section = {k.rpartition(".")[2]: k for k in keys() if k.rpartition(".")[0] == ".".join(parts[:-1])}
        close = close or [section[n] for n in [closest(parts[-1], section)] if n] \
            or [k for k in [closest(path, keys(), cutoff=0.8)] if k]   # a typo in the name, or in the section
        hint = f" (did you mean {close[0]}?)" if close else " (see --help for the keys)"
        raise ConfigError(f"unknown setting {path!r}{hint}")
    return fields[name][0], name, section


def coerce(path: str, raw: str) -> Any:
    """A string value for the dotted key ``path``, typed by the field's annotation."""
    ann, name, _ = _resolve(path)
    text = str(raw).strip()
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    optional = origin is typing.Union and type(None) in args
    if optional:
        if text.lower() in ("none", "null", ""):
            return None
        ann = next(a for a in args if a is not type(None))
        origin, args = typing.get_origin(ann), typing.get_args(ann)
    try:
        if ann is bool:
            low = text.lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise ValueError(text)
        if ann is int:
            f = float(text)
            if not f.is_integer():
                raise ValueError(text)
            return int(f)
        if ann is float:
            if "/" in text:  # a fraction, e.g. updates_per_step=1/0.6
                num, den = (float(x) for x in text.split("/"))
                return num / den
            return float(text)
        if ann is str:
            return text
        if origin is tuple and args == (float, float):  # a ratio: 0.6/0.4
            return parse_ratio(text)
        if origin is tuple:
            items = [x for x in text.replace("x", ",").split(",") if x.strip()]
            return tuple((args[0] if args and args[0] is not Ellipsis else int)(x) for x in items)
    except ConfigError:
        raise
    except (ValueError, ZeroDivisionError):
        pass
    raise ConfigError(f"bad value for {path}: {raw!r}")


def parse(item: str) -> Override:
    """'adapt.sac.lr=3e-4' -> Override; one ConfigError line naming the bad part."""
    if "=" not in str(item):
        raise ConfigError(f"a setting must look like KEY=VALUE (e.g. sac.lr=3e-4), got {item!r}")
    key, raw = (s.strip() for s in str(item).split("=", 1))
    stage = None
    head, _, rest = key.partition(".")
    if rest and (head in STAGE_WORDS or (head.startswith("stage") and head[5:].isdigit())):
        stage, key = head, rest
    return Override(key, coerce(key, raw), stage)


def parse_all(items: Iterable[str]) -> Tuple[Override, ...]:
    return tuple(parse(i) for i in items)


def apply(cfg: RunConfig, overrides: Sequence[Override], stage: Optional[int] = None,
          n_stages: int = 1) -> RunConfig:
    """A copy of ``cfg`` with the overrides that apply to this stage (None: a single-task run)."""
    d = cfg.to_dict()
    for o in overrides:
        if not o.applies_to(stage, n_stages):
            continue
        parts = o.path.split(".")
        target = d[parts[0]] if len(parts) == 2 else d
        target[parts[-1]] = o.value
    return RunConfig.from_dict(d)


def differences(a: RunConfig, b: RunConfig) -> List[str]:
    """'key=value' for every setting where ``b`` differs from ``a`` (for labels and docs)."""
    da, db = a.to_dict(), b.to_dict()
    out = []
    for k in keys():
        parts = k.split(".")
        va = da[parts[0]][parts[1]] if len(parts) == 2 else da[k]
        vb = db[parts[0]][parts[1]] if len(parts) == 2 else db[k]
        if va != vb:
            out.append(f"{k}={format_value(tuple(vb) if isinstance(vb, list) else vb)}")
    return out
