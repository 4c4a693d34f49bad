"""Pydantic schema of a scene file: every section, key, default and unit.

All quantities are SI: metres, seconds, kilograms, pascals.  Every model is strict and frozen:
unknown keys are rejected (with a "did you mean" suggestion), numbers must be real YAML numbers
(not booleans, not quoted strings) and finite, vectors are exactly three numbers and are stored as
tuples of float, and a validated scene cannot be changed afterwards.

Validators raise ``PydanticCustomError`` of type ``"softsim"`` whose context carries a short
message (``softsim_message``) and optionally the key it concerns (``softsim_key``, appended to the
error location) and the value to show (``softsim_value``); ``softsim.config.loader`` turns these
into one-line ``ConfigError`` messages.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from typing import Annotated, Any, Callable, ClassVar, Literal, Optional, Union

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]

# Sentinel: the error should not show a value (e.g. "mesh.size: required for shape 'box'").
NO_VALUE = object()

SHAPES = ("box", "cylinder", "sphere", "file")
MODELS = ("linear", "stvk", "corotated", "neohookean")
AXES = ("x", "y", "z")
DT_CHOICES = ("auto", "exact")
DT_POLICIES = ("substep", "refuse", "allow")
PRECISIONS = ("float64", "float32")
# Models with a float32 step: those with a displacement form (materials.models.DISPLACEMENT_FORM_MODELS).
FLOAT32_MODELS = ("linear", "stvk", "neohookean")
# Material limits [Pa], [kg/m^3] (see ``YoungsModulus``).
MAX_YOUNGS_MODULUS = 1e15
MIN_DENSITY = 1e-3
# Models that push an inverted element back (materials.models.INVERSION_SAFE); the guard stops the others.
INVERSION_SAFE_MODELS = ("corotated", "neohookean")
# The optional per-frame fields (softsim/io/fields.py says where each lives, its shape and unit).
OUTPUT_FIELDS = ("velocities", "energy", "displacement", "speed", "strain", "stress", "pressure",
                 "deviatoric_stress", "von_mises", "J")


def fail(message: str, key: Optional[str] = None, value: Any = None, show_value: bool = True):
    """Raise the validation error that the loader formats as ``<path>[.key] = <value>: message``.

    Without ``key`` the error belongs to the location being validated; with ``value`` left as
    ``None`` and ``show_value`` true, the loader shows the input pydantic reports.
    """
    ctx: dict[str, Any] = {"softsim_message": message}
    if key is not None:
        ctx["softsim_key"] = key
    if not show_value:
        ctx["softsim_value"] = NO_VALUE
    elif value is not None:
        ctx["softsim_value"] = value
    raise PydanticCustomError("softsim", "{softsim_message}", ctx)


# ---------------------------------------------------------------------------------------------
# Scalar and vector checks (used as BeforeValidators, so pydantic's lax coercion never runs first)


def _is_number(value: Any) -> bool:
    """True for int and float, but not bool (YAML ``yes``/``true``) and not strings."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _to_finite_float(value: Any) -> float:
    """``value`` as a finite float, or a validation error ("must be a number")."""
    if not _is_number(value):
        fail("must be a number")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        fail("must be a finite number")
    return number


def _range_text(gt: Optional[float], ge: Optional[float], lt: Optional[float]) -> str:
    """Human text of a range, e.g. ``"greater than -1 and less than 0.5"``."""
    parts = []
    if gt is not None:
        parts.append(f"greater than {gt:g}")
    if ge is not None:
        parts.append(f"at least {ge:g}")
    if lt is not None:
        parts.append(f"less than {lt:g}")
    return " and ".join(parts)


def _number_checker(
    gt: Optional[float] = None, ge: Optional[float] = None, lt: Optional[float] = None
) -> Callable[[Any], float]:
    """A validator accepting a finite int/float within the given open/closed bounds."""

    def check(value: Any) -> float:
        number = _to_finite_float(value)
        if (
            (gt is not None and not number > gt)
            or (ge is not None and not number >= ge)
            or (lt is not None and not number < lt)
        ):
            fail("must be " + _range_text(gt, ge, lt))
        return number

    return check


def _check_vec3(value: Any) -> Vec3:
    """Exactly three finite numbers (a YAML list) -> tuple of float."""
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 3
        or not all(_is_number(item) for item in value)
    ):
        fail("must be a list of 3 numbers [x, y, z]")
    return tuple(_to_finite_float(item) for item in value)  # type: ignore[return-value]


def _check_positive_vec3(value: Any) -> Vec3:
    """Three finite numbers, each > 0 (e.g. box extents)."""
    vector = _check_vec3(value)
    if not all(component > 0 for component in vector):
        fail("must be a list of 3 numbers [x, y, z], each greater than 0")
    return vector


def _check_mat3(value: Any) -> Mat3:
    """A 3x3 matrix: a list of three rows of three finite numbers -> tuple of row tuples."""
    message = "must be a 3x3 matrix (a list of 3 rows of 3 numbers)"
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        fail(message)
    rows = []
    for row in value:
        if not isinstance(row, (list, tuple)) or len(row) != 3:
            fail(message)
        if not all(_is_number(item) for item in row):
            fail(message)
        rows.append(tuple(_to_finite_float(item) for item in row))
    return tuple(rows)  # type: ignore[return-value]


def _choice_checker(options: tuple[str, ...]) -> Callable[[Any], str]:
    """A validator accepting exactly one of the strings ``options``."""

    def check(value: Any) -> str:
        if not isinstance(value, str) or value not in options:
            fail("must be one of " + ", ".join(options))
        return value

    return check


def _distinct_list_checker(options: tuple[str, ...], non_empty: bool) -> Callable[[Any], tuple]:
    """A validator accepting a list of distinct strings from ``options`` -> tuple of str."""
    what = "a non-empty list" if non_empty else "a list"
    message = f"must be {what} of distinct items from " + ", ".join(options)

    def check(value: Any) -> tuple[str, ...]:
        if not isinstance(value, (list, tuple)) or (non_empty and not value):
            fail(message)
        if not all(isinstance(item, str) and item in options for item in value):
            fail(message)
        if len(set(value)) != len(value):
            fail(message)
        return tuple(value)

    return check


def _check_bool(value: Any) -> bool:
    """Only YAML booleans (``true``/``false``), not 0/1 or strings."""
    if not isinstance(value, bool):
        fail("must be true or false")
    return value


def _check_path_string(value: Any) -> str:
    """A non-empty string (a file path)."""
    if not isinstance(value, str) or not value.strip():
        fail("must be a non-empty file path string")
    return value


def _check_list(value: Any) -> Any:
    """A YAML list (of sections); each item is then validated by its model."""
    if not isinstance(value, (list, tuple)):
        fail("must be a list")
    return value


def _check_dt(value: Any) -> Union[str, float]:
    """``"auto"``, ``"exact"`` or a positive finite number of seconds."""
    if isinstance(value, str) and value in DT_CHOICES:
        return value
    message = "must be 'auto', 'exact' or a positive number of seconds"
    if not _is_number(value):
        fail(message)
    try:
        seconds = float(value)
    except OverflowError:
        seconds = math.inf
    if not (math.isfinite(seconds) and seconds > 0):
        fail(message)
    return seconds


Positive = Annotated[float, BeforeValidator(_number_checker(gt=0.0))]
NonNegative = Annotated[float, BeforeValidator(_number_checker(ge=0.0))]
Real = Annotated[float, BeforeValidator(_number_checker())]
PoissonRatio = Annotated[float, BeforeValidator(_number_checker(gt=-1.0, lt=0.5))]
# Beyond any solid (diamond: E 1.2e12 Pa; aerogels: 1 kg/m^3), and far enough inside double
# precision that stiffness over mass, the stable step and the energies stay finite.
YoungsModulus = Annotated[float, BeforeValidator(_number_checker(gt=0.0, lt=MAX_YOUNGS_MODULUS))]
Density = Annotated[float, BeforeValidator(_number_checker(ge=MIN_DENSITY))]
Vector = Annotated[Vec3, BeforeValidator(_check_vec3)]
PositiveVector = Annotated[Vec3, BeforeValidator(_check_positive_vec3)]
Matrix = Annotated[Mat3, BeforeValidator(_check_mat3)]
Flag = Annotated[bool, BeforeValidator(_check_bool)]
FilePath = Annotated[str, BeforeValidator(_check_path_string)]
TimeStep = Annotated[Union[Literal["auto", "exact"], float], BeforeValidator(_check_dt)]
DtPolicy = Annotated[Literal["substep", "refuse", "allow"], BeforeValidator(_choice_checker(DT_POLICIES))]
Shape = Annotated[
    Literal["box", "cylinder", "sphere", "file"], BeforeValidator(_choice_checker(SHAPES))
]
ModelName = Annotated[
    Literal["linear", "stvk", "corotated", "neohookean"], BeforeValidator(_choice_checker(MODELS))
]
Axis = Annotated[Literal["x", "y", "z"], BeforeValidator(_choice_checker(AXES))]
Precision = Annotated[Literal["float64", "float32"], BeforeValidator(_choice_checker(PRECISIONS))]
AxisList = Annotated[tuple[str, ...], BeforeValidator(_distinct_list_checker(AXES, non_empty=True))]
FieldList = Annotated[
    tuple[str, ...], BeforeValidator(_distinct_list_checker(OUTPUT_FIELDS, non_empty=False))
]


# ---------------------------------------------------------------------------------------------
# Models


class Section(BaseModel):
    """Base of every scene section: strict, frozen, and helpful about unknown keys."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    # What an unknown key at this level is called in messages ("key" or "section").
    unknown_word: ClassVar[str] = "key"

    @model_validator(mode="before")
    @classmethod
    def _check_keys(cls, data: Any) -> Any:
        """The input must be a mapping whose keys are all fields; suggest close names."""
        if isinstance(data, BaseModel):
            return data
        allowed = list(cls.model_fields)
        if not isinstance(data, Mapping):
            fail("must be a mapping with keys " + ", ".join(allowed))
        for key in data:
            if key not in cls.model_fields:
                _unknown_key(str(key), allowed, cls.unknown_word, in_section=cls is not Scene)
        return data


def _unknown_key(key: str, allowed: list[str], word: str, in_section: bool = False) -> None:
    """Raise the "unknown key; did you mean ...?" error for ``key``; ``in_section``: the key lies
    inside a section, where a top-level key of that name is pointed to (``material.damping``)."""
    close = difflib.get_close_matches(key, allowed, n=1)
    if in_section and key in Scene.model_fields:
        hint = f"; '{key}' is a top-level key, not one of this section"
    else:
        hint = f"; did you mean '{close[0]}'?" if close else ""
    fail(f"unknown {word}{hint} (allowed: {', '.join(allowed)})", key=key, show_value=False)


class Mesh(Section):
    """Geometry of the body: a generated primitive (box, cylinder, sphere) or a mesh file."""

    shape: Shape = Field(description="box | cylinder | sphere | file (no unit)")
    size: Optional[PositiveVector] = Field(
        None, description="box extents [m] along x, y, z, each > 0; required for shape box"
    )
    origin: Vector = Field(
        (0.0, 0.0, 0.0),
        description="[m] box: min corner; cylinder: centre of the first end face; sphere: centre",
    )
    radius: Optional[Positive] = Field(
        None, description="cylinder/sphere radius [m] > 0; required for those shapes"
    )
    length: Optional[Positive] = Field(
        None, description="cylinder length [m] > 0 along its axis; required for cylinder"
    )
    axis: Axis = Field("x", description="cylinder axis direction: x | y | z (no unit)")
    element_size: Optional[Positive] = Field(
        None,
        description="gmsh target edge length [m] > 0; required for box/cylinder/sphere, "
        "ignored for file",
    )
    structured: Flag = Field(
        False, description="box only: true = structured hex cells split into 5 tets each"
    )
    file: Optional[FilePath] = Field(
        None,
        description="mesh file path for shape file (required then); relative to the scene "
        "file's directory, stored resolved to an absolute path",
    )

    @model_validator(mode="after")
    def _check_shape_keys(self) -> "Mesh":
        """Keys required by the shape are present; keys of other shapes are not set."""
        required = {
            "box": ("size", "element_size"),
            "cylinder": ("radius", "length", "element_size"),
            "sphere": ("radius", "element_size"),
            "file": ("file",),
        }[self.shape]
        for key in required:
            if getattr(self, key) is None:
                fail(f"required for shape '{self.shape}'", key=key, show_value=False)
        users = {"size": ("box",), "radius": ("cylinder", "sphere"), "length": ("cylinder",),
                 "file": ("file",)}
        for key, shapes in users.items():
            value = getattr(self, key)
            if value is not None and self.shape not in shapes:
                _not_for_shape(key, value, self.shape, shapes)
        if self.structured and self.shape != "box":
            _not_for_shape("structured", True, self.shape, ("box",))
        if self.axis != "x" and self.shape != "cylinder":
            _not_for_shape("axis", self.axis, self.shape, ("cylinder",))
        if self.origin != (0.0, 0.0, 0.0) and self.shape == "file":
            _not_for_shape("origin", self.origin, self.shape, ("box", "cylinder", "sphere"))
        return self


def _not_for_shape(key: str, value: Any, shape: str, shapes: tuple[str, ...]) -> None:
    """Raise "mesh.<key> = <value>: not used with shape '<shape>' (only with ...)"."""
    fail(f"not used with shape '{shape}' (only with {', '.join(shapes)})", key=key, value=value)


class Material(Section):
    """Isotropic elastic material law and its constants."""

    model: ModelName = Field(description="linear | stvk | corotated | neohookean (no unit)")
    youngs_modulus: YoungsModulus = Field(description="Young's modulus E [Pa], 0 < E < 1e15")
    poissons_ratio: PoissonRatio = Field(description="Poisson's ratio nu [-], -1 < nu < 0.5")
    density: Density = Field(description="mass density rho [kg/m^3] >= 1e-3")


class _Region(Section):
    """An axis-aligned box ``min <= x <= max`` [m] selecting mesh nodes or boundary faces."""

    min: Vector = Field(description="lower corner of the selection box [m]")
    max: Vector = Field(description="upper corner of the selection box [m], >= min")

    @model_validator(mode="after")
    def _check_corners(self) -> "_Region":
        """``min <= max`` in every component."""
        if any(lo > hi for lo, hi in zip(self.min, self.max)):
            fail(f"must be >= min {list(self.min)} in every component", key="max", value=self.max)
        return self


class FixedRegion(_Region):
    """Nodes inside the box follow a prescribed velocity along the chosen axes."""

    axes: AxisList = Field(
        ("x", "y", "z"), description="constrained axes: non-empty list of distinct x | y | z"
    )
    velocity: Vector = Field(
        (0.0, 0.0, 0.0), description="prescribed velocity [m/s] of the constrained components"
    )

    @model_validator(mode="after")
    def _check_velocity_axes(self) -> "FixedRegion":
        """No velocity along an axis the region does not hold (it would be ignored)."""
        free = [axis for axis, speed in zip("xyz", self.velocity) if speed != 0.0 and axis not in self.axes]
        if free:
            fail(f"non-zero along {', '.join(free)}, which axes: [{', '.join(self.axes)}] does not hold "
                 f"(a velocity is prescribed only along held axes)", key="velocity", value=list(self.velocity))
        return self


class TractionRegion(_Region):
    """Boundary faces inside the box carry a constant surface traction."""

    traction: Vector = Field(description="traction [Pa] (force per reference area) on the faces")


class InitialDeformation(Section):
    """Initial positions ``x = matrix @ X + translation`` of the reference nodes ``X`` [m]."""

    matrix: Matrix = Field(
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
        description="3x3 linear map [-] applied to the reference positions (rows)",
    )
    translation: Vector = Field((0.0, 0.0, 0.0), description="translation [m] added afterwards")


class Ground(Section):
    """A horizontal penalty ground plane ``z = height`` with Coulomb-like friction."""

    height: Real = Field(0.0, description="ground plane height z [m]")
    stiffness: Positive = Field(
        1.0e6, description="penalty stiffness [Pa/m] > 0: pressure per metre of penetration"
    )
    friction: NonNegative = Field(0.0, description="friction coefficient mu [-] >= 0")


class Time(Section):
    """Simulated time span and time step."""

    duration: Positive = Field(1.0, description="simulated time [s] > 0")
    dt: TimeStep = Field(
        "auto",
        description="time step [s] > 0; 'auto': a safety factor x the altitude / wave-speed estimate; "
        "'exact': from the largest eigenvalue of M^-1 K",
    )
    dt_policy: DtPolicy = Field(
        "substep",
        description="for a step above the stable one: substep (split it), refuse (error), allow (use it)",
    )


class Output(Section):
    """Where and how often frames are written."""

    path: FilePath = Field(
        "out.h5", description="HDF5 output file, relative to the working directory"
    )
    frame_interval: Positive = Field(0.01, description="simulated time between frames [s] > 0")
    fields: FieldList = Field(
        (), description="extra per-frame data: distinct items of velocities | energy | displacement | "
        "speed | strain | stress | pressure | deviatoric_stress | von_mises | J"
    )


Fixed = Annotated[tuple[FixedRegion, ...], BeforeValidator(_check_list)]
Tractions = Annotated[tuple[TractionRegion, ...], BeforeValidator(_check_list)]


class Scene(Section):
    """A complete scene: body, material, loads, constraints, contact, time and output."""

    unknown_word: ClassVar[str] = "section"

    mesh: Mesh = Field(description="geometry and meshing (lengths in m)")
    material: Material = Field(description="material law and constants (SI units)")
    precision: Precision = Field(
        "float64", description="floating point precision of the step: float64, or float32 (faster, about "
        "7 digits; linear, stvk and neohookean)"
    )
    damping: NonNegative = Field(0.0, description="damping rate [1/s] >= 0")
    gravity: Vector = Field((0.0, 0.0, -9.81), description="gravitational acceleration [m/s^2]")
    fixed: Fixed = Field((), description="fixed / driven regions (list)")
    tractions: Tractions = Field((), description="surface traction regions (list)")
    initial_deformation: InitialDeformation = Field(
        default_factory=InitialDeformation, description="initial affine map of the body"
    )
    initial_velocity: Vector = Field(
        (0.0, 0.0, 0.0), description="initial uniform velocity [m/s]"
    )
    angular_velocity: Vector = Field(
        (0.0, 0.0, 0.0),
        description="initial rigid-body angular velocity [rad/s]",
    )
    ground: Optional[Ground] = Field(None, description="ground plane; omitted/null = no ground")
    time: Time = Field(default_factory=Time, description="time span and step [s]")
    output: Output = Field(default_factory=Output, description="output file and frame rate")

    @model_validator(mode="after")
    def _check_precision(self) -> "Scene":
        """float32 only for the models that have a displacement form."""
        if self.precision == "float32" and self.material.model not in FLOAT32_MODELS:
            fail(f"material.model {self.material.model} steps in float64 only; float32 is available for "
                 f"{', '.join(FLOAT32_MODELS)}", key="precision", value=self.precision)
        return self

    @model_validator(mode="after")
    def _check_initial_orientation(self) -> "Scene":
        """linear and stvk cannot start from an initial map that turns every element inside out or
        flat (det <= 0): the guard, which stops them at any inverted element, would stop the run
        at its first frame."""
        (a, b, c), (d, e, f), (g, h, i) = self.initial_deformation.matrix
        det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
        if det <= 0.0 and self.material.model not in INVERSION_SAFE_MODELS:
            what = "flattens" if det == 0.0 else "turns inside out"
            fail(f"det = {det:.3g} {what} every element, which material.model {self.material.model} cannot "
                 f"recover from; use neohookean or corotated", key="initial_deformation.matrix",
                 value=[list(row) for row in self.initial_deformation.matrix])
        return self


SECTION_NAMES = tuple(Scene.model_fields)
