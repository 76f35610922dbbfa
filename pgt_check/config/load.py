"""Strict loading of plain data (a JSON/TOML file or the CLI) into the frozen config
dataclasses of ``pgt_check.config``: type checks per field (``from_dict``), the range and
backend-name checks their ``__post_init__`` use, config files and the recursive merge of
settings. Knows no config class: ``pgt_check.config`` imports it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from pathlib import Path
from typing import Any, Literal

from pgt_check.common.files import MAX_SMALL_JSON_BYTES, read_text_limited
from pgt_check.errors import ConfigError, InputError


def check_range(
    where: str,
    value: float | int | None,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> None:
    """``value`` (None = unset, allowed) must be finite and within [lo, hi] (open ends if asked).

    The one range check of every numeric option (CLI and config files both end here); raises
    ValueError, which ``from_dict`` turns into a ConfigError naming ``where``."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{where}: must be a finite number, got {value!r}")
    below = lo is not None and (value <= lo if lo_open else value < lo)
    above = hi is not None and (value >= hi if hi_open else value > hi)
    if below or above:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        lo_s = "-inf" if lo is None else f"{lo:g}"
        hi_s = "inf" if hi is None else f"{hi:g}"
        raise ValueError(f"{where}: {value!r} is out of range {left}{lo_s}, {hi_s}{right}")


def check_name(section: str, key: str, value: str, table: Any) -> None:
    """``value`` must be a key of the backend table ``table`` (the one source of the names)."""
    if value not in table:
        raise ValueError(f"{section}.{key}: unknown {value!r} (allowed: {', '.join(table)})")


#: spellings of a boolean accepted from the command line and config files (case-insensitive)
BOOL_WORDS = {
    "true": True, "yes": True, "on": True, "1": True,
    "false": False, "no": False, "off": False, "0": False,
}


def parse_bool(value: Any) -> bool:
    """A boolean from a config value or a command-line word: true/false, yes/no, on/off, 1/0
    (strings in any case, surrounding blanks ignored; the integers 1 and 0). Anything else
    raises ValueError: a typo ('ture') must not read as false and switch a check off."""
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in BOOL_WORDS:
        return BOOL_WORDS[value.strip().lower()]
    raise ValueError(f"expected true/false (or yes/no, on/off, 1/0), got {value!r}")


def _check_value(cls_name: str, name: str, tp: Any, value: Any) -> Any:
    origin = typing.get_origin(tp)
    if origin is Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(
                f"{cls_name}.{name}: {value!r} is not one of {list(typing.get_args(tp))}"
            )
        return value
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _check_value(cls_name, name, a, value)
            except ConfigError:
                continue
        raise ConfigError(f"{cls_name}.{name}: {value!r} does not fit {tp}")
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        if not isinstance(value, dict):
            raise ConfigError(f"{cls_name}.{name}: expected a table, got {value!r}")
        return from_dict(tp, value)
    if tp is bool:
        try:
            return parse_bool(value)
        except ValueError as err:
            raise ConfigError(f"{cls_name}.{name}: {err}") from None
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{cls_name}.{name}: expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{cls_name}.{name}: expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{cls_name}.{name}: expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type, data: dict[str, Any]):
    """Build dataclass ``cls`` from ``data``; unknown keys and mistyped values raise ConfigError."""
    if not isinstance(data, dict):
        raise ConfigError(f"{cls.__name__}: expected a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted((k for k in data if k not in fields), key=repr)  # any key type
    if unknown:
        raise ConfigError(
            f"{cls.__name__}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(fields))})"
        )
    kwargs = {k: _check_value(cls.__name__, k, hints[k], v) for k, v in data.items()}
    try:
        return cls(**kwargs)
    except ValueError as err:  # range and name checks name their key themselves
        raise ConfigError(str(err)) from err
    except TypeError as err:
        raise ConfigError(f"{cls.__name__}: {err}") from err


class DuplicateKeyError(ValueError):
    """A JSON object that names one key twice (``json.loads`` would keep the last silently)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``object_pairs_hook`` of config JSON: a key given twice in one object is an error, as
    TOML has it (``{"gate": {"max_fail_fraction": 0.0, "max_fail_fraction": 1.0}}`` must not
    read as 1.0)."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKeyError(f"duplicate key {key!r}")
        out[key] = value
    return out


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read a JSON or TOML config file into a dict (validated later by ``from_dict``)."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"config file not found: {path}")
    try:
        text = read_text_limited(path, MAX_SMALL_JSON_BYTES, "config file")
        if path.suffix == ".toml":
            import tomllib

            data = tomllib.loads(text)
        else:
            data = json.loads(text, object_pairs_hook=_unique_keys)
    except InputError as err:  # a special or oversized file, bytes that are not UTF-8
        raise ConfigError(f"cannot read config: {err}") from err
    except RecursionError:
        raise ConfigError(f"{path}: cannot parse config: nested too deeply") from None
    except DuplicateKeyError as err:
        raise ConfigError(f"{path}: cannot parse config: {err} (each key once per table)"
                          ) from None
    except ValueError as err:  # JSON / TOML syntax
        raise ConfigError(f"{path}: cannot parse config: {err}") from err
    if not isinstance(data, dict):
        raise ConfigError(
            f"{path}: expected a table of settings at the top level, got {type(data).__name__}"
        )
    return data


def merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Recursive dict merge: values in ``override`` win; nested tables merge."""
    out = dict(base)
    for k, v in override.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = merge(out[k], v)
        else:
            out[k] = v
    return out
