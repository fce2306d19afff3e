"""The one way this project reads a YAML settings file: typed sections with their rules beside the fields.

A settings file is described by frozen dataclasses that derive from :class:`Section`. Each field
carries its type and its single-value rules in its annotation; rules that span several fields live
in the section's :meth:`Section.check`. Validation is pydantic v2's (a ``TypeAdapter`` of the
dataclass, built once per class): unknown keys are refused, every value is checked, and the first
problem becomes one line naming the dotted key path and the file, e.g.::

    ppo.learning_rate must be > 0, got -1.0 (configs/ppo.yaml)
    unknown config key 'task.cube.colour'; allowed keys here: ['jitter', 'mass', ...] (configs/task.yaml)

Adding a key is one line in the section (and the value in its YAML file)::

    num_workers: Annotated[Int, ge(1), le(64)]  # processes collecting in parallel

The sections stay plain frozen dataclasses: attribute access costs what a dataclass's does (no
validation after loading), ``dataclasses.replace`` works as before (and, as before, does not
validate: tests and ``deploy.merge_safety`` build deliberately out-of-range copies), and
:meth:`Section.to_dict` gives back the YAML-shaped mapping that :meth:`Section.from_dict` reads
(``from_dict(x.to_dict()) == x``), so a run folder stores the resolved configuration from the typed
object. Fields marked :func:`derived` (e.g. radians computed from a ``*_deg`` key) are filled by
:meth:`Section.derive` after validation and are not written back.

Per-key rules that are not validation ride in the same annotation as markers that pydantic
ignores: :func:`legacy` (what a file written before the key existed behaved as; one generic
:func:`fill_legacy` fills such files) and :func:`stricter` (for a safety key, which of two values
is the stricter; deploy's ``merge_safety`` reads it). :func:`markers` lists a section's markers.

Scalars are strict: :data:`Int` refuses booleans, floats and strings; :data:`Float` takes integers
and the numeric strings YAML 1.1 produces for ``1e-4`` but refuses booleans, other strings, NaN
and infinities; :data:`Bool` takes only true/false; :data:`Str` only strings. Choices are
``Literal[...]`` and report the allowed values.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Callable, Literal, Mapping, Sequence, TypeVar

import yaml
from pydantic import AfterValidator, ConfigDict, PlainValidator, TypeAdapter, ValidationError
from pydantic_core import PydanticCustomError, core_schema

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file, key or value is invalid; the message names which (one line)."""


# ----------------------------------------------------------------------------------------------
# Scalars and rules.  A rule's message is appended to the key path: " must be > 0, got -1".
# ----------------------------------------------------------------------------------------------


def fail(text: str) -> typing.NoReturn:
    """Raise inside a validator: ``text`` follows the key path (start it with ": " or " ")."""
    raise PydanticCustomError("config", "{text}", {"text": text})


# The numbers YAML 1.1 (PyYAML) reads as strings: an exponent without a dot or its sign ("1e-4",
# "2.5e3"). Any other string (a quoted "2", "x") is refused.
_EXPONENT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def _float(value: Any) -> float:
    if isinstance(value, str):  # YAML 1.1 reads "1e-4" as a string
        if not _EXPONENT.fullmatch(value.strip()):
            fail(f": expected a number, got {value!r}")
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        fail(f": expected a number, got {value!r}")
    if not math.isfinite(value):
        fail(f": must be finite, got {value!r}")
    return float(value)


def _int(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        fail(f": expected an integer, got {value!r}")
    return value


def _bool(value: Any) -> bool:
    if not isinstance(value, bool):
        fail(f": expected true/false, got {value!r}")
    return value


def _str(value: Any) -> str:
    if not isinstance(value, str):
        fail(f": expected a string, got {value!r}")
    return value


Float = Annotated[float, PlainValidator(_float)]
Int = Annotated[int, PlainValidator(_int)]
Bool = Annotated[bool, PlainValidator(_bool)]
Str = Annotated[str, PlainValidator(_str)]


def _path(value: Any) -> str | None:
    """A path string (not blank) or None."""
    if value is not None and (not isinstance(value, str) or not value.strip()):
        fail(f" must be a path string or null, got {value!r}")
    return value


FilePath = Annotated[typing.Optional[str], PlainValidator(_path)]  # a file's path, or null: not set


def _bound(op: str, limit: float, ok: Callable[[Any], bool], what: str) -> AfterValidator:
    def check(value: Any) -> Any:
        if not ok(value):
            fail(f" must be {op} {limit}{what}, got {value!r}")
        return value
    return AfterValidator(check)


def gt(limit: float, what: str = "") -> AfterValidator:
    """Rule: value > limit."""
    return _bound(">", limit, lambda v: v > limit, what)


def ge(limit: float, what: str = "") -> AfterValidator:
    """Rule: value >= limit."""
    return _bound(">=", limit, lambda v: v >= limit, what)


def le(limit: float, what: str = "") -> AfterValidator:
    """Rule: value <= limit (``what``: units or a reason appended to the limit)."""
    return _bound("<=", limit, lambda v: v <= limit, what)


def within(lo: float, hi: float, closed: str = "[]") -> AfterValidator:
    """Rule: value in the interval from ``lo`` to ``hi``; ``closed`` is "[]", "[)", "(]" or "()"."""
    def check(value: Any) -> Any:
        above = value >= lo if closed[0] == "[" else value > lo
        below = value <= hi if closed[1] == "]" else value < hi
        if not (above and below):
            fail(f" must be in {closed[0]}{lo}, {hi}{closed[1]}, got {value!r}")
        return value
    return AfterValidator(check)


def count(least: int, most: int | None = None) -> AfterValidator:
    """Rule for a variable-length list: ``least`` .. ``most`` entries."""
    def check(value: Sequence) -> Sequence:
        if len(value) < least or (most is not None and len(value) > most):
            span = f"at least {least}" if most is None else f"{least} to {most}"
            fail(f" must list {span} values, got {list(value)}")
        return value
    return AfterValidator(check)


def ordered() -> AfterValidator:
    """Rule for a range ``(lo, hi)`` or a box of them (``((lo, hi), ...)``), or None: every
    ``lo <= hi``."""
    def check(value: Sequence | None) -> Sequence | None:
        if value is None:
            return None
        pairs = [value] if value and not isinstance(value[0], (tuple, list)) else value
        if any(lo > hi for lo, hi in pairs):
            shown = [list(p) for p in pairs] if pairs is value else list(value)
            fail(f" must be [lo, hi] with lo <= hi per range, got {shown}")
        return value
    return AfterValidator(check)


def unit_quaternion(tolerance: float) -> AfterValidator:
    """Rule for a quaternion (w, x, y, z), or None: its norm within ``tolerance`` of 1 (rounding in
    a hand-written file, never a wrong rotation); the value is returned divided by its norm."""
    def check(value: Sequence[float] | None) -> tuple[float, ...] | None:
        if value is None:
            return None
        import numpy as np

        norm = float(np.linalg.norm(value))
        if abs(norm - 1.0) > tolerance:
            fail(f" must be a unit quaternion (w, x, y, z; norm {norm:.6g}), got {list(value)}")
        return tuple(float(v) for v in np.divide(value, norm))
    return AfterValidator(check)


class FrozenDict(dict):
    """A read-only, hashable mapping for mapping-valued fields (a section stays hashable)."""

    def __hash__(self) -> int:  # type: ignore[override]
        return hash(tuple(sorted(self.items())))

    def __reduce__(self) -> tuple:  # copy and pickle (Ray) rebuild it whole
        return (type(self), (dict(self),))

    def _refuse(self, *args: Any, **kwargs: Any) -> typing.NoReturn:
        raise TypeError("a configuration mapping is read-only")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = _refuse  # type: ignore


def derived(**kwargs: Any) -> Any:
    """A field computed by :meth:`Section.derive` from other fields; not read from or written to
    YAML (a file that names it is refused as an unknown key)."""
    return dataclasses.field(default=None, metadata={"derived": True}, **kwargs)


# ----------------------------------------------------------------------------------------------
# Per-key markers, written in a field's annotation beside its rules:
#
#     sleep: Annotated[Bool, legacy(False)]  # a run written before the key existed: no sleeping
#     table_margin: Annotated[NonNeg, stricter("higher")]  # m; deploy keeps the larger one
#
# legacy(): what a run folder's config.yaml written before the key existed behaved as (read by
# fill_legacy); stricter(): for a safety key, which of two values is the stricter (read by
# deploy's merge_safety). Pydantic ignores both.
# ----------------------------------------------------------------------------------------------

MISSING: Any = type("Missing", (), {"__repr__": lambda self: "MISSING"})()  # "no value": leave the key out


@dataclasses.dataclass(frozen=True, eq=False)
class Legacy:
    """Marker: a mapping written before this key existed takes ``value`` (a YAML-shaped value,
    copied) or, with ``rule``, ``rule(section, root)``: the value computed from the section's
    mapping and the whole mapping as read (:data:`MISSING`: leave the key out, for the schema to
    name). A section's value may itself lack keys whose fields carry their own markers."""

    value: Any = None
    rule: Callable[[Mapping[str, Any], Mapping[str, Any]], Any] | None = None

    def fill(self, section: Mapping[str, Any], root: Mapping[str, Any]) -> Any:
        """The value for a mapping that lacks the key."""
        return self.rule(section, root) if self.rule is not None else copy.deepcopy(self.value)


def legacy(value: Any) -> Legacy:
    """Marker: runs written before the key existed behaved as if it held ``value`` (YAML-shaped:
    lists, mappings, plain scalars; a literal, so that an old run's behaviour does not move when
    the repository's default does)."""
    return Legacy(value)


def legacy_rule(rule: Callable[[Mapping[str, Any], Mapping[str, Any]], Any]) -> Legacy:
    """Marker: runs written before the key existed behaved as if it held ``rule(section, root)``
    (e.g. a value computed from the keys of that time); :data:`MISSING` leaves the key out."""
    return Legacy(rule=rule)


Direction = Literal["on", "higher", "lower", "none"]
DIRECTIONS: tuple[str, ...] = typing.get_args(Direction)


@dataclasses.dataclass(frozen=True)
class Stricter:
    """Marker of a safety key: which of two values is the stricter. ``on``: true (a boolean);
    ``higher`` / ``lower``: the larger / smaller number, entry by entry for a vector; ``none``: no
    order (a solver setting, a set of pairs): the deploying side's value is used."""

    direction: Direction


def stricter(direction: Direction) -> Stricter:
    """Marker: the stricter direction of a safety key (one of :data:`DIRECTIONS`)."""
    if direction not in DIRECTIONS:
        raise ValueError(f"stricter({direction!r}): choose one of {list(DIRECTIONS)}")
    return Stricter(direction)


def _marker(cls: type, name: str, kind: type[T]) -> T | None:
    """The ``kind`` marker in the annotation of ``cls``'s field ``name`` (None if it has none)."""
    hint = typing.get_type_hints(cls, include_extras=True)[name]
    found = [m for m in getattr(hint, "__metadata__", ()) if isinstance(m, kind)]
    return found[-1] if found else None


@functools.lru_cache(maxsize=None)
def markers(cls: type, kind: type) -> dict[str, Any]:
    """Field name -> its ``kind`` marker (:class:`Legacy` or :class:`Stricter`) or None, for every
    field of the section ``cls`` read from YAML (not :func:`derived`), in field order."""
    return {f.name: _marker(cls, f.name, kind) for f in dataclasses.fields(cls) if not f.metadata.get("derived")}


@functools.lru_cache(maxsize=None)
def section_fields(cls: type) -> dict[str, type]:
    """Field name -> the Section type of each field of ``cls`` that is itself a section."""
    hints = typing.get_type_hints(cls, include_extras=True)
    out = {}
    for field in dataclasses.fields(cls):
        tp = _strip(hints[field.name])
        if isinstance(tp, type) and issubclass(tp, Section):
            out[field.name] = tp
    return out


def fill_legacy(cls: type, data: Any, root: Mapping[str, Any] | None = None) -> Any:
    """``data`` (a YAML-shaped mapping for the section ``cls``) with every missing key whose field
    carries a :func:`legacy` marker filled, in nested sections too; ``data`` itself is not changed
    (a copy is made only where something is filled). Anything but a dict is returned as it is, for
    the schema to name. ``root``: the whole mapping, for :func:`legacy_rule` (default ``data``)."""
    if not isinstance(data, dict):
        return data
    root = data if root is None else root
    out = data
    sections = section_fields(cls)
    for name, mark in markers(cls, Legacy).items():
        value = data.get(name, MISSING)
        if value is MISSING and mark is not None:
            value = mark.fill(data, root)
        if name in sections and value is not MISSING:
            value = fill_legacy(sections[name], value, root)
        if value is not data.get(name, MISSING):
            if out is data:
                out = dict(data)
            out[name] = value
    return out


# ----------------------------------------------------------------------------------------------
# Sections.
# ----------------------------------------------------------------------------------------------

S = TypeVar("S", bound="Section")


class Section:
    """Base of every settings section (use with ``@dataclasses.dataclass(frozen=True)``).

    Single-value rules go in the field annotations (``Annotated[Float, gt(0)]``); rules that
    relate several fields go in :meth:`check`; computed fields (:func:`derived`) are filled in
    :meth:`derive`. Nothing here runs after loading: attribute access is a dataclass's.
    """

    __pydantic_config__ = ConfigDict(extra="forbid")

    @classmethod
    def __get_pydantic_core_schema__(cls, source: Any, handler: Any) -> Any:
        """The dataclass's own schema, refusing :func:`derived` fields as keys."""
        schema = handler(source)
        names = [f.name for f in dataclasses.fields(cls) if f.metadata.get("derived")]
        if not names:
            return schema

        def refuse(data: Any) -> Any:
            if isinstance(data, Mapping):
                for name in names:
                    if name in data:
                        raise PydanticCustomError("derived_key", "{name} is computed, not read", {"name": name})
            return data
        return core_schema.no_info_before_validator_function(refuse, schema)

    def derive(self) -> None:
        """Fill the :func:`derived` fields (``object.__setattr__``); runs before :meth:`check`, and
        may raise :class:`ConfigError` as it does (a value that cannot be derived)."""

    def check(self, key: str) -> None:
        """Rules across fields; raise :class:`ConfigError` with a message that names ``key``'s
        fields (``key`` is this section's dotted path, e.g. ``task.episode``). Runs after the
        nested sections' checks."""

    def to_dict(self) -> dict:
        """The YAML-shaped mapping (lists, plain scalars; no derived fields) that :meth:`from_dict`
        reads back into an equal object."""
        return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self)
                if not f.metadata.get("derived")}

    @classmethod
    def from_dict(cls: type[S], data: Any, key: str = "", source: Source | None = None,
                  error: type[Exception] = ConfigError) -> S:
        """Validate ``data`` (a parsed YAML mapping) into this section; see :func:`validate`."""
        return validate(cls, data, key, source, error)


def _plain(value: Any) -> Any:
    if isinstance(value, Section):
        return value.to_dict()
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def keys_of(cls: type) -> list[str]:
    """The keys a section's YAML mapping may hold (its non-derived fields), sorted."""
    return sorted(f.name for f in dataclasses.fields(cls) if not f.metadata.get("derived"))


# ----------------------------------------------------------------------------------------------
# Validation and its one-line errors.
# ----------------------------------------------------------------------------------------------

# Where values came from, for the message's "(file)" note: one path, a mapping from the first key
# of the path (a section) to its file, or a callable key -> text (or None for no note).
Source = typing.Union[str, Path, Mapping[str, typing.Union[str, Path]], Callable[[str], "str | None"]]


def show_path(path: str | Path) -> str:
    """``path`` relative to the working directory when it lies below it (shorter messages)."""
    path = Path(path)
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def source_note(source: Source | None, key: str) -> str:
    """' (where)': the note that ends a message about ``key`` (empty without a source)."""
    if source is None:
        return ""
    if callable(source):
        text = source(key)
    elif isinstance(source, Mapping):
        path = source.get(key.split(".")[0].split("[")[0])
        text = show_path(path) if path is not None else None
    else:
        text = show_path(source)
    return f" ({text})" if text else ""


@functools.lru_cache(maxsize=None)
def _adapter(tp: Any) -> TypeAdapter:
    return TypeAdapter(tp)


def _join(key: str, loc: Sequence[Any]) -> str:
    out = key
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out = f"{out}.{part}" if out else str(part)
    return out


def _strip(tp: Any) -> Any:
    """``tp`` without Annotated metadata and without the None of an Optional."""
    while True:
        if typing.get_origin(tp) is Annotated:
            tp = typing.get_args(tp)[0]
        elif typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp):
            rest = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(rest) != 1:
                return tp
            tp = rest[0]
        else:
            return tp


def _type_at(tp: Any, loc: Sequence[Any]) -> Any:
    """The (unannotated) type found by following ``loc`` from ``tp``; None when lost."""
    for part in loc:
        tp = _strip(tp)
        if dataclasses.is_dataclass(tp) and isinstance(part, str):
            hints = typing.get_type_hints(tp, include_extras=True)
            if part not in hints:
                return None
            tp = hints[part]
        elif typing.get_origin(tp) is tuple and isinstance(part, int):
            args = typing.get_args(tp)
            tp = args[0] if len(args) == 2 and args[1] is Ellipsis else (args[part] if part < len(args) else None)
        elif typing.get_origin(tp) in (dict, Mapping) or typing.get_origin(tp) is typing.Mapping:
            tp = typing.get_args(tp)[1]
        else:
            return None
        if tp is None:
            return None
    return _strip(tp)


def _message(root: Any, key: str, err: Mapping[str, Any]) -> tuple[str, str]:
    """(the key path, the one-line message) of one pydantic error."""
    loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]
    where = _join(key, loc)
    kind, value = err["type"], err.get("input")
    if kind == "config":
        return where, f"{where}{err['ctx']['text']}"
    if kind == "derived_key":  # a computed field named in the file
        kind, loc = "extra_forbidden", [*loc, err["ctx"]["name"]]
        where = _join(key, loc)
    if kind in ("unexpected_keyword_argument", "extra_forbidden"):
        parent = _type_at(root, loc[:-1])
        allowed = keys_of(parent) if dataclasses.is_dataclass(parent) else []
        return where, f"unknown config key '{where}'; allowed keys here: {allowed}"
    if kind == "missing" and loc and isinstance(loc[-1], int):
        parent = _join(key, loc[:-1])
        size = len(typing.get_args(_type_at(root, loc[:-1])) or ())
        return parent, f"{parent}: expected {size} values, got {len(value)}: {value!r}"
    if kind == "too_long":
        return where, (f"{where}: expected {err['ctx'].get('max_length')} values, got "
                       f"{err['ctx'].get('actual_length')}: {value!r}")
    if kind == "missing":
        return where, f"missing config key '{where}'"
    if kind == "literal_error":
        tp = _type_at(root, loc)
        allowed = list(typing.get_args(tp)) if typing.get_origin(tp) is Literal else \
            re.findall(r"'([^']*)'", err.get("ctx", {}).get("expected", ""))
        return where, f"{where}: {value!r} is not allowed; choose one of {allowed}"
    if kind in ("dataclass_type", "dataclass_args_type", "dict_type", "mapping_type"):
        return where, f"{where or 'config'}: expected a mapping, got {value!r}"
    if kind in ("tuple_type", "list_type", "iterable_type"):
        return where, f"{where}: expected a list, got {value!r}"
    if kind == "string_type":
        return where, f"{where}: expected a string, got {value!r}"
    return where, f"{where}: {err['msg']}, got {value!r}"


def _finish(obj: Any, key: str, error: type[Exception], source: Source | None) -> None:
    """Derive and check every section below ``obj`` (children first)."""
    if isinstance(obj, Section):
        for field in dataclasses.fields(obj):
            _finish(getattr(obj, field.name), f"{key}.{field.name}" if key else field.name, error, source)
        try:
            obj.derive()
            obj.check(key)
        except ConfigError as problem:
            raise error(f"{problem}{source_note(source, key)}") from None
    elif isinstance(obj, dict):
        for name, value in obj.items():
            _finish(value, f"{key}.{name}" if key else str(name), error, source)
    elif isinstance(obj, tuple):
        for value in obj:
            if isinstance(value, Section):
                _finish(value, key, error, source)



def validate(tp: type[T] | Any, data: Any, key: str = "", source: Source | None = None,
             error: type[Exception] = ConfigError) -> T:
    """``data`` (parsed YAML) validated as ``tp`` (a :class:`Section` or e.g. ``dict[str, S]``),
    its sections derived and checked; raises ``error`` (default :class:`ConfigError`) with one line
    naming the key path (prefixed by ``key``) and where the value came from (``source``)."""
    try:
        obj = _adapter(tp).validate_python(data)
    except ValidationError as problem:
        errors = problem.errors()
        unknown = [e for e in errors if e["type"] in ("unexpected_keyword_argument", "extra_forbidden",
                                                      "derived_key")]
        where, text = _message(tp, key, (unknown or errors)[0])  # a misspelt key before its "missing"
        raise error(f"{text}{source_note(source, where)}") from None
    _finish(obj, key, error, source)
    return obj


# ----------------------------------------------------------------------------------------------
# Files and overrides.
# ----------------------------------------------------------------------------------------------


_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's safe loader when built (same YAML)


def read_yaml(path: Path | str, error: type[Exception] = ConfigError) -> dict:
    """The mapping at the top of a YAML file; one-line ``error`` for a missing, broken or
    non-mapping file."""
    path = Path(path)
    if not path.is_file():
        raise error(f"config file not found: {path}")
    try:
        data = yaml.load(path.read_text(), Loader=_LOADER)
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    except OSError as exc:
        raise error(f"cannot read {path}: {exc.strerror}") from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a mapping at the top level")
    return data


def apply_override(data: dict, override: str) -> None:
    """Apply one ``dotted.key=value`` override (value parsed as YAML) to a nested dict, in place;
    the key must exist already."""
    if "=" not in override:
        raise ConfigError(f"override {override!r} must look like key.sub=value")
    dotted, raw = override.split("=", 1)
    parts = dotted.strip().split(".")
    node = data
    for i, part in enumerate(parts):
        if not isinstance(node, dict):
            raise ConfigError(f"config key '{'.'.join(parts[:i])}' in override {override!r} is a value, "
                              "not a section with keys")
        if part not in node:
            raise ConfigError(f"unknown config key '{'.'.join(parts[: i + 1])}' in override {override!r}; "
                              f"allowed keys here: {sorted(node)}")
        if i < len(parts) - 1:
            node = node[part]
    try:
        node[parts[-1]] = yaml.safe_load(raw)
    except yaml.YAMLError:
        raise ConfigError(f"override {override!r}: value is not valid YAML") from None


def override_keys(overrides: Sequence[str]) -> list[str]:
    """The dotted keys that ``key=value`` overrides set."""
    return [item.split("=", 1)[0].strip() for item in overrides if "=" in item]


def load_file(cls: type[S], path: Path | str, key: str = "", overrides: Sequence[str] = (),
              error: type[Exception] = ConfigError) -> S:
    """Read ``path``, apply ``key=value`` overrides (keys relative to the file) and validate it as
    ``cls``; messages name keys as ``key.<path>`` and end with the file (or "override")."""
    data = read_yaml(path, error)
    for item in overrides:
        apply_override(data, item)
    changed = override_keys(overrides)
    prefix = f"{key}." if key else ""

    def note(where: str) -> str:
        inner = where[len(prefix):] if where.startswith(prefix) else where
        hit = any(inner == k or inner.startswith(f"{k}.") or inner.startswith(f"{k}[") for k in changed)
        return "override" if hit else show_path(path)

    return validate(cls, data, key, note, error)
