"""The sweep file: its strict schema, and its expansion into runs, each a re-validated scene.

A sweep file names a base scene and the scene keys to vary::

    base: cantilever.yaml            # a scene file relative to the sweep file, or an inline mapping
    parameters:                      # dotted scene keys; the cartesian product of all of them
      material.youngs_modulus: [5.0e7, 1.0e8, 2.0e8]
      material.poissons_ratio: {start: 0.2, stop: 0.45, num: 6}     # log: true for log spacing
    zip:                             # optional: keys that vary together (equal-length lists)
      mesh.element_size: [0.04, 0.02]
      time.dt: [2.0e-5, 1.0e-5]
    set:                             # optional: values every run uses (not in run names)
      time.duration: 0.5

``load_sweep`` validates the file (one-line ``ConfigError`` naming the key, the value and what
is allowed); ``expand_sweep`` makes every combination a full scene, validated by the scene
schema before anything runs, with its output file named after its parameter values.
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import itertools
import math
import re
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Union

import yaml
from pydantic import BaseModel, BeforeValidator, Field, ValidationError, model_validator

from ..config import Scene, Section, parse_scene
from ..config.loader import LIST_ITEM, read_yaml, set_key_path, validation_message
from ..config.schema import fail
from ..errors import ConfigError

# Values of a range are rounded to this many significant digits (0.25, not 0.25000000000000006).
RANGE_DIGITS = 12
# At most this many runs in one sweep (each is a whole simulation).
MAX_RUNS = 100_000
# Output names longer than this many characters are cut and end in a hash of the whole name.
MAX_NAME_CHARS = 200
# The keys the sweep itself sets for each run.
RESERVED_KEYS = ("output.path",)


# ---------------------------------------------------------------------------------------------
# Schema


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite_number(value: Any) -> float:
    if not _is_number(value) or not math.isfinite(float(value)):
        fail("must be a finite number")
    return float(value)


def _check_count(value: Any) -> int:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        fail("must be a whole number of values, at least 1")
    return value


def _check_flag(value: Any) -> bool:
    if not isinstance(value, bool):
        fail("must be true or false")
    return value


class Range(Section):
    """``num`` values from ``start`` to ``stop`` (both included), evenly or (``log``) geometrically spaced."""

    start: Annotated[float, BeforeValidator(_finite_number)] = Field(description="first value")
    stop: Annotated[float, BeforeValidator(_finite_number)] = Field(description="last value")
    num: Annotated[int, BeforeValidator(_check_count)] = Field(description="number of values >= 1")
    log: Annotated[bool, BeforeValidator(_check_flag)] = Field(False, description="geometric spacing")

    @model_validator(mode="before")
    @classmethod
    def _check_required(cls, data: Any) -> Any:
        for key in ("start", "stop", "num"):
            if isinstance(data, Mapping) and key not in data:
                fail("required key missing (a range is {start, stop, num} and optionally log)", key=key,
                     show_value=False)
        return data

    @model_validator(mode="after")
    def _check_log(self) -> "Range":
        if self.log and not (self.start > 0 and self.stop > 0):
            fail("must be greater than 0 with log: true", key="start" if self.start <= 0 else "stop",
                 value=self.start if self.start <= 0 else self.stop)
        return self

    def values(self) -> tuple[float, ...]:
        """The ``num`` values, rounded to ``RANGE_DIGITS`` significant digits."""
        if self.num == 1:
            raw = [self.start]
        elif self.log:
            ratio = math.log(self.stop / self.start) / (self.num - 1)
            raw = [self.start * math.exp(ratio * i) for i in range(self.num)]
            raw[-1] = self.stop
        else:
            step = (self.stop - self.start) / (self.num - 1)
            raw = [self.start + step * i for i in range(self.num)]
            raw[-1] = self.stop
        return tuple(float(f"{value:.{RANGE_DIGITS}g}") for value in raw)


def _section_of(annotation: Any):
    """The ``Section`` model a field holds (through Optional / Annotated), or None for a leaf
    (a number, a vector, or a list of sections such as ``fixed``: varied as a whole)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (tuple, list):
        return None
    for argument in typing.get_args(annotation):
        found = _section_of(argument)
        if found is not None:
            return found
    return None


def _item_section_of(annotation: Any):
    """The section class of the items of a list-of-sections field annotation (``fixed``), or None."""
    if typing.get_origin(annotation) is tuple:
        arguments = typing.get_args(annotation)
        if arguments and isinstance(arguments[0], type) and issubclass(arguments[0], BaseModel):
            return arguments[0]
    return None


def _is_value_list(annotation: Any) -> bool:
    """Whether a field annotation is a list of values (a vector, optional or not)."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return _is_value_list(typing.get_args(annotation)[0])
    return origin is tuple or (origin is Union and any(_is_value_list(a) for a in typing.get_args(annotation)))


def check_scene_key(key: str) -> None:
    """Raise a validation error unless ``key`` (``material.youngs_modulus``, ``fixed[1].velocity``,
    ``mesh.size[0]``) names a scene key or section; whether a list item exists is for the base
    scene to say."""
    model = Scene
    parts = key.split(".")
    for depth, part in enumerate(parts):
        where = ".".join(parts[:depth])
        if model is None:
            fail(f"is not a scene key: {where} is a value or a list, not a section; vary {where} as a whole",
                 key=key, show_value=False)
        item = LIST_ITEM.match(part)
        if item is not None and item["name"] in model.model_fields:
            annotation = model.model_fields[item["name"]].annotation
            model = _item_section_of(annotation)
            if model is None and _is_value_list(annotation):
                if depth + 1 == len(parts):
                    return                  # a component of a vector (mesh.size[0]); the base says if it exists
                fail(f"is not a scene key: {'.'.join(parts[:depth + 1])} is a value, not a section",
                     key=key, show_value=False)
            if model is None:
                fail(f"is not a scene key: {'.'.join(parts[:depth] + [item['name']])} is not a list",
                     key=key, show_value=False)
            continue
        if part in model.model_fields and depth + 1 < len(parts):
            items = _item_section_of(model.model_fields[part].annotation)
            if items is not None:
                named = ".".join(parts[: depth + 1])
                fail(f"is not a scene key: {named} is a list; name an item, as {named}[0].{parts[depth + 1]}",
                     key=key, show_value=False)
        if part not in model.model_fields:
            allowed = list(model.model_fields)
            close = difflib.get_close_matches(part, allowed, n=1)
            hint = f"; did you mean '{'.'.join(parts[:depth] + [close[0]])}'?" if close else ""
            inside = f" of {where}" if where else " of a scene"
            fail(f"is not a scene key{hint} (keys{inside}: {', '.join(allowed)})", key=key, show_value=False)
        model = _section_of(model.model_fields[part].annotation)
    if key in RESERVED_KEYS:
        fail("is set by the sweep: each run writes <output folder>/<run name>.h5", key=key, show_value=False)


def _check_values(key: str, values: Any, where: str) -> tuple:
    """A non-empty list of values for ``key`` (a range mapping is allowed under ``parameters``)."""
    if where == "parameters" and isinstance(values, Mapping):
        try:
            points = Range.model_validate(values).values()
        except ValidationError as error:
            fail(validation_message(error), key=key, show_value=False)
        if len(set(points)) < len(points):
            fail(f"gives repeated values {list(points)}; use a larger range or a smaller num", key=key,
                 show_value=False)
        return points
    if not isinstance(values, (list, tuple)) or not values:
        allowed = "a non-empty list of values or a range {start, stop, num, log}" if where == "parameters" \
            else "a non-empty list of values"
        fail(f"must be {allowed}", key=key, value=values)
    shown = [yaml.safe_dump(value, default_flow_style=True) for value in values]
    for i, text in enumerate(shown if where == "parameters" else ()):   # zip lists may repeat
        if text in shown[:i]:
            fail(f"the value {values[i]!r} is listed twice", key=key, value=list(values))
    return tuple(values)


def _values_checker(where: str):
    def check(value: Any) -> dict:
        if value is None:
            return {}
        if not isinstance(value, Mapping):
            fail("must be a mapping of dotted scene keys (material.youngs_modulus) to lists of values")
        result = {}
        for key, values in value.items():
            if not isinstance(key, str) or not key:
                fail("keys must be dotted scene keys like material.youngs_modulus", key=str(key),
                     show_value=False)
            check_scene_key(key)
            name = canonical_key(key)
            if name in result:
                fail(f"is given twice (as {name})", key=key, show_value=False)
            result[name] = _check_values(name, values, where)
        return result

    return check


def _check_fixed_values(value: Any) -> dict:
    """``set``: dotted scene key -> one value, the same in every run."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        fail("must be a mapping of dotted scene keys (time.duration) to one value each")
    for key in value:
        if not isinstance(key, str) or not key:
            fail("keys must be dotted scene keys like time.duration", key=str(key), show_value=False)
        check_scene_key(key)
    result = {}
    for key, one in value.items():
        name = canonical_key(key)
        if name in result:
            fail(f"is given twice (as {name})", key=key, show_value=False)
        result[name] = copy.deepcopy(one)
    return result


def _check_base(value: Any) -> Union[str, dict]:
    if isinstance(value, str) and value.strip():
        return value
    if isinstance(value, Mapping):
        return copy.deepcopy(dict(value))
    fail("must be a scene file path (relative to the sweep file) or an inline scene mapping")


class SweepFile(Section):
    """A sweep: a base scene, the keys to vary (cartesian ``parameters``, parallel ``zip``) and fixed ``set`` values."""

    unknown_word: typing.ClassVar[str] = "section"

    base: Annotated[Union[str, dict], BeforeValidator(_check_base)] = Field(
        description="scene file (relative to the sweep file) or inline scene mapping")
    parameters: Annotated[dict, BeforeValidator(_values_checker("parameters"))] = Field(
        default_factory=dict, description="dotted scene key -> list of values or {start, stop, num, log}")
    zip: Annotated[dict, BeforeValidator(_values_checker("zip"))] = Field(
        default_factory=dict, description="dotted scene key -> list of values; all lists of equal length")
    set: Annotated[dict, BeforeValidator(_check_fixed_values)] = Field(
        default_factory=dict, description="dotted scene key -> one value for every run (not in run names)")

    @model_validator(mode="after")
    def _check_varied_keys(self) -> "SweepFile":
        if not self.parameters and not self.zip:
            fail("required: at least one scene key to vary, under parameters or zip", key="parameters",
                 show_value=False)
        lengths = {key: len(values) for key, values in self.zip.items()}
        if len(set(lengths.values())) > 1:
            first = next(iter(lengths))
            for key, length in lengths.items():
                if length != lengths[first]:
                    fail(f"has {length} values but {first} has {lengths[first]}; zip lists vary together "
                         f"and must have equal length", key=f"zip.{key}", show_value=False)
        keys = [*self.parameters, *self.zip, *self.set]
        for a, b in itertools.permutations(keys, 2):
            if a == b or b.startswith((a + ".", a + "[")):
                what = "is given twice (parameters, zip, set)" if a == b else f"overlaps {a}"
                fail(f"{what}; each scene key may be varied once", key=b, show_value=False)
        return self


# ---------------------------------------------------------------------------------------------
# Runs


@dataclass(frozen=True)
class Run:
    """One combination: its number (from 0), file name stem, parameter values and validated scene."""

    index: int
    name: str
    parameters: dict
    scene: Scene

    @property
    def path(self) -> Path:
        return Path(self.scene.output.path)


@dataclass(frozen=True)
class Sweep:
    """A validated sweep file: the raw base scene, the folder it is relative to, the swept keys and
    ``fixed`` (the file's ``set``: values every run uses)."""

    source: str
    base: dict
    base_dir: Path
    parameters: dict
    zip: dict
    fixed: dict

    @property
    def keys(self) -> tuple[str, ...]:
        return (*self.parameters, *self.zip)

    @property
    def run_count(self) -> int:
        count = math.prod(len(values) for values in self.parameters.values())
        if self.zip:
            count *= len(next(iter(self.zip.values())))
        return count


def parse_sweep(data: Any, base_dir: Union[str, Path] = ".", source: str = "sweep") -> Sweep:
    """Validate a raw sweep mapping; a base scene file is read relative to ``base_dir``."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: a sweep file must be a mapping with keys base, parameters, zip, set")
    try:
        sweep_file = SweepFile.model_validate(data)
    except ValidationError as error:
        raise ConfigError(f"{source}: {validation_message(error)}") from None
    base_dir = Path(base_dir).absolute()
    if isinstance(sweep_file.base, str):
        scene_path = base_dir / sweep_file.base
        base = read_yaml(scene_path, "base scene file")
        if not isinstance(base, Mapping):
            raise ConfigError(f"base = {sweep_file.base!r}: the scene file {scene_path} is not a mapping")
        base_dir = scene_path.parent
    else:
        base = sweep_file.base
    return Sweep(source=source, base=dict(base), base_dir=base_dir, parameters=sweep_file.parameters,
                 zip=sweep_file.zip, fixed=sweep_file.set)


def load_sweep(path: Union[str, Path]) -> Sweep:
    """Read and validate the sweep file ``path`` (``ConfigError`` with one line on any problem)."""
    path = Path(path)
    data = read_yaml(path, "sweep file")
    if data is None:
        raise ConfigError(f"{path}: the sweep file is empty; it needs base and parameters (or zip)")
    if isinstance(data, Mapping) and "mesh" in data and "base" not in data:
        raise ConfigError(f"{path}: is a scene file (it has 'mesh', and no 'base'); run it with softsim run {path}, "
                          f"or sweep it from a sweep file whose base it is")
    return parse_sweep(data, path.absolute().parent, source=str(path))


def format_value(value: Any) -> str:
    """A value as it appears in a run name: the shortest ``g`` form of a float (``1e+08``, ``0.3``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        for digits in range(1, 18):
            text = f"{value:.{digits}g}"
            if float(text) == value:
                return text
        return repr(value)
    if isinstance(value, (list, tuple)):
        return ",".join(format_value(item) for item in value)
    if isinstance(value, Mapping):
        return ",".join(f"{key}:{format_value(item)}" for key, item in value.items())
    return str(value)


_UNSAFE = re.compile(r"[^A-Za-z0-9._+,:=-]")


def run_name(parameters: Mapping, labels: Mapping) -> str:
    """The file-name stem of a run: ``label=value`` pairs joined by ``__``, safe on every file system.

    Characters other than letters, digits and ``. _ + , = -`` become ``_``; a name over
    ``MAX_NAME_CHARS`` is cut and ends in a hash of the whole name.
    """
    name = "__".join(f"{labels[key]}={format_value(value)}" for key, value in parameters.items())
    name = _UNSAFE.sub("_", name.replace(":", "-"))
    if name.startswith("."):
        name = "_" + name[1:]
    if len(name) > MAX_NAME_CHARS:
        digest = hashlib.sha1(name.encode()).hexdigest()[:10]
        name = f"{name[:MAX_NAME_CHARS - 12]}__{digest}"
    return name


def labels_for(keys) -> dict:
    """Each swept key's label in run names: its last part (an item number as ``_0``: ``size_0``), or
    the whole key where two would clash."""
    last = [_numbered(key.rsplit(".", 1)[-1]) for key in keys]
    return {key: short if last.count(short) == 1 else _numbered(key) for key, short in zip(keys, last)}


def _numbered(key: str) -> str:
    """``key`` with its item numbers written for a file name: ``fixed[0].min`` -> ``fixed_0.min``."""
    return re.sub(r"\[(\d+)\]", r"_\1", key)


def canonical_key(key: str) -> str:
    """``key`` with its item numbers written plainly (``fixed[00]`` -> ``fixed[0]``), so that two
    spellings of one key are seen as the same key."""
    return re.sub(r"\[(\d+)\]", lambda number: f"[{int(number[1])}]", key)


def combinations(sweep: Sweep):
    """Each run's parameters, in order: ``{key: value}`` with ``parameters`` keys first (the first slowest)."""
    zipped = list(zip(*sweep.zip.values())) if sweep.zip else [()]
    for values in itertools.product(*sweep.parameters.values(), zipped):
        point = dict(zip(sweep.parameters, values[:-1]))
        point.update(zip(sweep.zip, values[-1]))
        yield point


def expand_sweep(sweep: Sweep, output_dir: Union[str, Path]) -> list[Run]:
    """Every combination as a ``Run`` whose scene is validated and writes ``output_dir/<name>.h5``.

    Raises ``ConfigError`` naming the run and the key for the first invalid combination, and for
    two runs that would write the same file.
    """
    count = sweep.run_count
    if count > MAX_RUNS:
        raise ConfigError(f"{sweep.source}: {count} runs; a sweep may have at most {MAX_RUNS}")
    output_dir = Path(output_dir).absolute()
    labels = labels_for(sweep.keys)
    runs, names = [], {}
    for index, point in enumerate(combinations(sweep)):
        name = run_name(point, labels)
        if name in names:
            raise ConfigError(f"runs {names[name] + 1} and {index + 1} of {count} would both write {name}.h5; "
                              f"give them values that differ in their first 17 digits")
        names[name] = index
        data = copy.deepcopy(dict(sweep.base))     # once a run; the keys are set in place
        try:
            for key, value in [*sweep.fixed.items(), *point.items(), ("output.path", str(output_dir / f"{name}.h5"))]:
                set_key_path(data, key.split("."), copy.deepcopy(value), key)
            scene = parse_scene(data, sweep.base_dir)
        except ConfigError as error:
            raise ConfigError(f"run {index + 1} of {count} ({name}): {error}") from None
        runs.append(Run(index=index, name=name, parameters=point, scene=scene))
    return runs
