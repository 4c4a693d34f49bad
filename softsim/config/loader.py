"""Read a scene file: YAML -> overrides -> validation -> resolved mesh path.

Every problem becomes a one-line ``ConfigError`` that names the key path (``fixed[0].min``), the
offending value and what is allowed.  Nothing here prints or exits.
"""

from __future__ import annotations

import copy
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Union

import yaml
from pydantic import ValidationError

from ..errors import ConfigError
from .schema import NO_VALUE, SECTION_NAMES, Scene

# At most this many validation problems are joined into one message.
_MAX_REPORTED = 3
# Longer shown values are cut to this many characters.
_MAX_VALUE_CHARS = 60

_MAPPING_REQUIRED = (
    "the scene must be a mapping with sections " + ", ".join(SECTION_NAMES)
    + " (mesh and material are required)"
)


# ---------------------------------------------------------------------------------------------
# YAML


# YAML 1.2 style floats: 1e6, 2.0e11, -3E-4, .5, 1., plus .inf/.nan (rejected later by the schema).
_FLOAT_RE = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?[0-9][0-9_]*\.(?:[eE][-+]?[0-9]+)?
        |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
    re.X,
)
_FLOAT_TAG = "tag:yaml.org,2002:float"


class SceneLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that reads ``1e6`` as a float and rejects duplicate keys.

    PyYAML follows YAML 1.1, where a float needs a dot (``1.0e+6``); scene files use the YAML 1.2
    spelling.  ``yes``/``no``/``on``/``off`` stay booleans (the schema rejects them as numbers).
    """

    def construct_mapping(self, node, deep=False):
        """Build a mapping, refusing a key that appears twice (PyYAML keeps the last silently)."""
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
            except TypeError:
                continue  # unhashable: the base class reports it
            if duplicate:
                raise yaml.constructor.ConstructorError(
                    "while constructing a mapping", node.start_mark,
                    f"found duplicate key {key!r}", key_node.start_mark,
                )
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _install_float_resolver() -> None:
    """Replace the inherited YAML 1.1 float resolver of ``SceneLoader`` by ``_FLOAT_RE``."""
    resolvers = {
        first: [(tag, regexp) for tag, regexp in entries if tag != _FLOAT_TAG]
        for first, entries in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    SceneLoader.yaml_implicit_resolvers = resolvers
    SceneLoader.add_implicit_resolver(_FLOAT_TAG, _FLOAT_RE, list("-+0123456789."))


_install_float_resolver()


def _one_line(text: str) -> str:
    """Collapse whitespace (PyYAML messages span several lines)."""
    return " ".join(str(text).split())


def _yaml_error_message(error: yaml.YAMLError, where: str) -> str:
    """One line: ``<where>: invalid YAML at line L, column C: <problem>``."""
    mark = getattr(error, "problem_mark", None) or getattr(error, "context_mark", None)
    problem = getattr(error, "problem", None)
    if mark is not None:
        context = getattr(error, "context", None)
        detail = _one_line(": ".join(part for part in (context, problem) if part))
        return f"{where}: invalid YAML at line {mark.line + 1}, column {mark.column + 1}: {detail}"
    return f"{where}: invalid YAML: {_one_line(error)}"


def read_yaml(path: Path, what: str = "scene file") -> Any:
    """Parse the YAML file ``path`` with ``SceneLoader``; ``what`` names it in errors."""
    try:
        with open(path, "rb") as stream:
            return yaml.load(stream, Loader=SceneLoader)
    except FileNotFoundError:
        raise ConfigError(f"{what} not found: {path}") from None
    except OSError as error:
        raise ConfigError(f"cannot read {what} {path}: {error.strerror or error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(_yaml_error_message(error, str(path))) from None


# ---------------------------------------------------------------------------------------------
# Overrides


def apply_overrides(data: Mapping, overrides: Iterable[str]) -> dict:
    """A copy of ``data`` with each ``"dotted.key=value"`` override applied in order.

    The value is parsed with ``SceneLoader`` (``1e6`` -> float, ``[1, 2, 3]`` -> list, empty ->
    null).  A key may index a list item, as the error messages name them (``fixed[0].min``).
    Missing intermediate keys (or null ones) become new mappings; a path through a scalar, a list
    without an index, or an index past a list's end is an error.
    """
    result = copy.deepcopy(dict(data))
    if isinstance(overrides, str):
        overrides = (overrides,)
    for override in overrides:
        keys, value = _parse_override(override)
        set_key_path(result, keys, value, f"override {override!r}")
    return result


def _parse_override(override: Any) -> tuple[list[str], Any]:
    """``"a.b=1e6"`` -> ``(["a", "b"], 1000000.0)``."""
    if not isinstance(override, str) or "=" not in override:
        raise ConfigError(
            f"override {override!r}: must look like key.path=value, e.g. material.density=1200"
        )
    path, text = override.split("=", 1)
    keys = [key.strip() for key in path.split(".")]
    if not all(keys):
        raise ConfigError(f"override {override!r}: the key path {path.strip()!r} has an empty part")
    try:
        value = yaml.load(text, Loader=SceneLoader)
    except yaml.YAMLError as error:
        raise ConfigError(_yaml_error_message(error, f"override {override!r}")) from None
    return keys, value


LIST_ITEM = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<index>\d+)\]$")


def set_key_path(data: dict, keys: list[str], value: Any, label: str) -> None:
    """Set ``data[k0][k1]...[kn] = value`` in place, creating mappings on the way; a key ``name[i]``
    is item ``i`` of the list ``name``.  ``ConfigError`` messages start with ``label`` (what set it)."""
    steps: list[Union[str, int]] = []
    for key in keys:
        item = LIST_ITEM.match(key)
        if item is None and ("[" in key or "]" in key):
            raise ConfigError(f"{label}: {key!r} is no key; a list item is named by its "
                              f"number from 0, as fixed[0]")
        steps += [item["name"].strip(), int(item["index"])] if item else [key]
    node: Any = data
    for depth, (step, next_step) in enumerate(zip(steps[:-1], steps[1:])):
        where = _dotted(steps[: depth + 1])
        if isinstance(step, int):                  # node is a list (checked below, one step up)
            if step >= len(node):
                raise ConfigError(f"{label}: {_dotted(steps[:depth])} has {len(node)} "
                                  f"item{'s' if len(node) != 1 else ''}, so no {where}")
            child = node[step]
        else:
            child = node.get(step)
        item = f"{where}[{next_step}]"
        if isinstance(next_step, int) and child is None:
            raise ConfigError(f"{label}: {where} has no items, so no {item}; give the whole list as {where}")
        if isinstance(next_step, int):
            if not isinstance(child, list):
                raise ConfigError(f"{label}: {where} is {_show(child)}, not a list, so no {item}")
            child = list(child)
        elif child is None:
            child = {}
        elif isinstance(child, Mapping):
            child = dict(child)
        elif isinstance(child, list):
            raise ConfigError(f"{label}: {where} is a list, so it has no key {next_step!r}; "
                              f"name an item, as {where}[0]")
        else:
            raise ConfigError(f"{label}: {where} is {_show(child)}, not a mapping, "
                              f"so it has no key {next_step!r}")
        node[step] = child
        node = child
    last = steps[-1]
    if isinstance(last, int) and last >= len(node):
        raise ConfigError(f"{label}: {_dotted(steps[:-1])} has {len(node)} "
                          f"item{'s' if len(node) != 1 else ''}, so no {_dotted(steps)}")
    node[last] = value


# ---------------------------------------------------------------------------------------------
# Validation errors -> one line


def _show(value: Any) -> str:
    """A short, YAML-flavoured rendering of an offending value."""
    if value is None:
        text = "null"
    elif isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, tuple):
        text = repr(list(value))
    else:
        text = repr(value)
    if len(text) > _MAX_VALUE_CHARS:
        text = text[: _MAX_VALUE_CHARS - 3] + "..."
    return text


def _dotted(loc: Iterable[Any]) -> str:
    """``("fixed", 0, "min")`` -> ``"fixed[0].min"``."""
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text


def _error_line(error: dict) -> str:
    """One pydantic error dict as ``path = value: what is allowed``."""
    loc = tuple(error.get("loc", ()))
    ctx = error.get("ctx") or {}
    kind = error.get("type")
    if kind == "softsim":
        if "softsim_key" in ctx:
            loc += (ctx["softsim_key"],)
        value = ctx.get("softsim_value", error.get("input"))
        message = ctx["softsim_message"]
    elif kind == "missing":
        return f"{_dotted(loc)}: " + (
            "required section missing" if len(loc) == 1 else "required key missing"
        )
    elif kind == "extra_forbidden":
        return f"{_dotted(loc)}: unknown key"
    else:  # a pydantic check the schema does not wrap (should not happen)
        value = error.get("input")
        message = _one_line(error.get("msg", "invalid value")).removeprefix("Value error, ")
    path = _dotted(loc) or "scene"
    if value is NO_VALUE:
        return f"{path}: {message}"
    return f"{path} = {_show(value)}: {message}"


def validation_message(error: ValidationError) -> str:
    """The first few problems of ``error`` joined into one line."""
    problems = error.errors(include_url=False)
    lines = [_error_line(problem) for problem in problems[:_MAX_REPORTED]]
    extra = len(problems) - _MAX_REPORTED
    if extra > 0:
        lines.append(f"and {extra} more problem{'s' if extra > 1 else ''}")
    return "; ".join(lines)


# ---------------------------------------------------------------------------------------------
# Public API


def parse_scene(data: Any, base_dir: Union[str, Path] = ".") -> Scene:
    """Validate a raw scene mapping; ``mesh.file`` is resolved against ``base_dir`` and checked."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{_MAPPING_REQUIRED}; got {_show(data)}")
    try:
        scene = Scene.model_validate(data)
    except ValidationError as error:
        raise ConfigError(validation_message(error)) from None
    return _resolve_mesh_file(scene, Path(base_dir))


def load_scene(path: Union[str, Path], overrides: Iterable[str] = ()) -> Scene:
    """Read, override and validate the scene file ``path``.

    ``overrides`` are ``"dotted.key=value"`` strings applied to the raw YAML before validation.
    A relative ``mesh.file`` is taken relative to the scene file's directory.
    """
    path = Path(path)
    data = read_yaml(path)
    if not isinstance(data, Mapping):
        got = "an empty file" if data is None else _show(data)
        raise ConfigError(f"{path}: {_MAPPING_REQUIRED}; got {got}")
    if "base" in data and "mesh" not in data:
        raise ConfigError(f"{path}: is a sweep file (it has 'base', and no 'mesh'); run it with softsim sweep {path}")
    data = apply_overrides(data, overrides)
    return parse_scene(data, base_dir=path.absolute().parent)


class _SceneDumper(yaml.SafeDumper):
    """Block-style mappings, with lists of plain values (vectors, rows) written inline."""


def _represent_list(dumper: yaml.SafeDumper, items: list) -> yaml.Node:
    inline = all(not isinstance(item, (list, dict)) for item in items)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", items, flow_style=inline)


_SceneDumper.add_representer(list, _represent_list)


def scene_to_yaml(scene: Scene) -> str:
    """The fully resolved scene (every default filled in) as YAML text.

    Mesh keys that do not apply to the shape (``None``) are left out; everything else is written,
    so ``parse_scene(yaml.load(text, Loader=SceneLoader)) == scene``.
    """
    data = scene.model_dump(mode="json")
    data["mesh"] = {key: value for key, value in data["mesh"].items() if value is not None}
    return yaml.dump(data, Dumper=_SceneDumper, sort_keys=False, allow_unicode=True)


def _resolve_mesh_file(scene: Scene, base_dir: Path) -> Scene:
    """``scene`` with ``mesh.file`` made absolute; the file must exist and be readable."""
    given = scene.mesh.file
    if given is None:
        return scene
    resolved = os.path.abspath(os.path.join(base_dir, os.path.expanduser(given)))
    if not os.path.isfile(resolved):
        what = "is not a file" if os.path.exists(resolved) else "not found"
        raise ConfigError(f"mesh.file = {given!r}: mesh file {what} (looked for {resolved})")
    try:
        with open(resolved, "rb"):
            pass
    except OSError as error:
        raise ConfigError(
            f"mesh.file = {given!r}: mesh file {resolved} is not readable "
            f"({error.strerror or error})"
        ) from None
    mesh = scene.mesh.model_copy(update={"file": resolved})
    return scene.model_copy(update={"mesh": mesh})
