"""Scene schema and loader: defaults, YAML number parsing, error messages, overrides, round trip."""

import copy

import pytest
import yaml
from pydantic import ValidationError

from softsim.config import (
    FixedRegion,
    Ground,
    Scene,
    SceneLoader,
    Section,
    apply_overrides,
    load_scene,
    parse_scene,
    scene_to_yaml,
)
from softsim.errors import ConfigError

MINIMAL = {
    "mesh": {"shape": "box", "size": [1.0, 0.1, 0.1], "element_size": 0.02},
    "material": {"model": "stvk", "youngs_modulus": 1.0e8, "poissons_ratio": 0.3, "density": 1000},
}

MINIMAL_YAML = """\
mesh:
  shape: box
  size: [1, 0.1, 0.1]
  element_size: 0.02
material:
  model: stvk
  youngs_modulus: 2.0e11
  poissons_ratio: 0.3
  density: 8e3
"""


def with_overrides(*overrides):
    """MINIMAL with ``key=value`` overrides applied (values parsed as YAML)."""
    return apply_overrides(MINIMAL, overrides)


def config_error(data, base_dir="."):
    """The message of the ConfigError that ``parse_scene(data)`` must raise."""
    with pytest.raises(ConfigError) as info:
        parse_scene(data, base_dir=base_dir)
    message = str(info.value)
    assert "\n" not in message
    assert "pydantic" not in message and "http" not in message
    return message


def write(tmp_path, text, name="scene.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


# ---------------------------------------------------------------------------------------------
# Defaults and types


def test_minimal_scene_gets_all_defaults():
    scene = parse_scene(MINIMAL)
    assert scene.mesh.shape == "box"
    assert scene.mesh.size == (1.0, 0.1, 0.1)
    assert scene.mesh.origin == (0.0, 0.0, 0.0)
    assert scene.mesh.axis == "x"
    assert scene.mesh.structured is False
    assert scene.mesh.file is None
    assert scene.material.density == 1000.0 and isinstance(scene.material.density, float)
    assert scene.precision == "float64"
    assert scene.damping == 0.0
    assert scene.gravity == (0.0, 0.0, -9.81)
    assert scene.fixed == () and scene.tractions == ()
    assert scene.initial_deformation.matrix == ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    assert scene.initial_deformation.translation == (0.0, 0.0, 0.0)
    assert scene.initial_velocity == (0.0, 0.0, 0.0)
    assert scene.angular_velocity == (0.0, 0.0, 0.0)
    assert scene.ground is None
    assert scene.time.duration == 1.0 and scene.time.dt == "auto"
    assert scene.output.path == "out.h5"
    assert scene.output.frame_interval == 0.01
    assert scene.output.fields == ()


def test_sub_sections_get_their_defaults():
    scene = parse_scene(
        with_overrides(
            "ground={}",
            "fixed=[{min: [0, 0, 0], max: [0.01, 1, 1]}]",
            "tractions=[{min: [1, 0, 0], max: [1, 1, 1], traction: [1e4, 0, 0]}]",
            "time.dt=1e-5",
        )
    )
    assert scene.ground == Ground(height=0.0, stiffness=1.0e6, friction=0.0)
    assert scene.fixed[0] == FixedRegion(
        min=(0, 0, 0), max=(0.01, 1, 1), axes=("x", "y", "z"), velocity=(0, 0, 0)
    )
    assert scene.tractions[0].traction == (1.0e4, 0.0, 0.0)
    assert scene.time.dt == 1e-5 and isinstance(scene.time.dt, float)


def test_every_field_has_a_description():
    def models(cls):
        yield cls
        for field in cls.model_fields.values():
            for arg in (field.annotation, *getattr(field.annotation, "__args__", ())):
                if isinstance(arg, type) and issubclass(arg, Section):
                    yield from models(arg)

    for cls in models(Scene):
        for name, field in cls.model_fields.items():
            assert field.description, f"{cls.__name__}.{name}"


def test_exponent_numbers_load_as_floats(tmp_path):
    scene = load_scene(write(tmp_path, MINIMAL_YAML))
    assert scene.material.youngs_modulus == 2.0e11
    assert scene.material.density == 8.0e3
    data = yaml.load("[1e6, 2.0e11, -3E-4, .5, -.5e-3, 12, yes, 1.2.3]", Loader=SceneLoader)
    assert data == [1.0e6, 2.0e11, -3e-4, 0.5, -5e-4, 12, True, "1.2.3"]
    assert all(type(value) is float for value in data[:5])


def test_frozen():
    scene = parse_scene(MINIMAL)
    with pytest.raises(ValidationError):
        scene.damping = 1.0
    with pytest.raises(ValidationError):
        scene.material.density = 1.0


# ---------------------------------------------------------------------------------------------
# Error messages


@pytest.mark.parametrize(
    "override, expected",
    [
        ("material.poissons_ratio=0.7",
         "material.poissons_ratio = 0.7: must be greater than -1 and less than 0.5"),
        ("material.poissons_ratio=-1", "material.poissons_ratio = -1: must be greater than -1"),
        ("material.model=steel",
         "material.model = 'steel': must be one of linear, stvk, corotated, neohookean"),
        ("material.density=heavy", "material.density = 'heavy': must be a number"),
        ("material.density='1e6'", "material.density = '1e6': must be a number"),
        ("material.youngs_modulus=-5", "material.youngs_modulus = -5: must be greater than 0"),
        ("material.youngs_modulus=1e200",
         "material.youngs_modulus = 1e+200: must be greater than 0 and less than 1e+15"),
        ("material.density=1e-300", "material.density = 1e-300: must be at least 0.001"),
        ("material.density=0", "material.density = 0: must be at least 0.001"),
        ("time.dt=-1", "time.dt = -1: must be 'auto', 'exact' or a positive number of seconds"),
        ("time.dt=fast", "time.dt = 'fast': must be 'auto', 'exact' or a positive number of seconds"),
        ("time.duration=0", "time.duration = 0: must be greater than 0"),
        ("damping=-0.5", "damping = -0.5: must be at least 0"),
        ("gravity=[0, -9.81]", "gravity = [0, -9.81]: must be a list of 3 numbers"),
        ("initial_velocity=3", "initial_velocity = 3: must be a list of 3 numbers"),
        ("precision=float16", "precision = 'float16': must be one of float64, float32"),
        ("mesh.shape=blob", "mesh.shape = 'blob': must be one of box, cylinder, sphere, file"),
        ("mesh.size=[1, 0, 1]",
         "mesh.size = [1, 0, 1]: must be a list of 3 numbers [x, y, z], each greater than 0"),
        ("mesh.size=[1, 1]", "mesh.size = [1, 1]: must be a list of 3 numbers"),
        ("mesh.element_size=0", "mesh.element_size = 0: must be greater than 0"),
        ("mesh.structured=1", "mesh.structured = 1: must be true or false"),
        ("mesh.radius=0.05", "mesh.radius = 0.05: not used with shape 'box'"),
        ("initial_deformation.matrix=[[1, 0, 0], [0, 1, 0]]",
         "initial_deformation.matrix = [[1, 0, 0], [0, 1, 0]]: must be a 3x3 matrix"),
        ("fixed=[{min: [0, 0, 0], max: [1, -1, 1]}]",
         "fixed[0].max = [1.0, -1.0, 1.0]: must be >= min [0.0, 0.0, 0.0] in every component"),
        ("fixed=[{min: [0, 0, a], max: [1, 1, 1]}]", "fixed[0].min = [0, 0, 'a']: must be a list"),
        ("fixed=[{min: [0, 0, 0], max: [1, 1, 1], axes: [x, x]}]",
         "fixed[0].axes = ['x', 'x']: must be a non-empty list of distinct items from x, y, z"),
        ("fixed=[{min: [0, 0, 0], max: [1, 1, 1], axes: []}]", "fixed[0].axes = []: must be"),
        ("fixed={min: [0, 0, 0]}", "fixed = {'min': [0, 0, 0]}: must be a list"),
        ("fixed=[{min: [0, 0, 0], max: [1, 1, 1], axes: [x], velocity: [0, 1.0, 0]}]",
         "fixed[0].velocity = [0.0, 1.0, 0.0]: non-zero along y, which axes: [x] does not hold"),
        ("fixed=[{min: [0, 0, 0], max: [1, 1, 1], axes: [z, x], velocity: [1, 2, 3]}]",
         "fixed[0].velocity = [1.0, 2.0, 3.0]: non-zero along y, which axes: [z, x] does not hold"),
        ("initial_deformation.matrix=[[-1, 0, 0], [0, 1, 0], [0, 0, 1]]",
         "initial_deformation.matrix = [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]: det = -1 turns "
         "inside out every element, which material.model stvk cannot recover from; use neohookean or corotated"),
        ("initial_deformation.matrix=[[0, 0, 0], [0, 1, 0], [0, 0, 1]]",
         "initial_deformation.matrix = [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]: det = 0 flattens"),
        ("tractions=[{min: [0, 0, 0], max: [1, 1, 1]}]", "tractions[0].traction: required key"),
        ("ground.stiffness=0", "ground.stiffness = 0: must be greater than 0"),
        ("ground.friction=-0.1", "ground.friction = -0.1: must be at least 0"),
        ("output.fields=[energy, energy]", "output.fields = ['energy', 'energy']: must be"),
        ("output.fields=[tension]", "output.fields = ['tension']: must be a list of distinct items"),
        ("output.frame_interval=0", "output.frame_interval = 0: must be greater than 0"),
        ("output.path=", "output.path = null: must be a non-empty file path string"),
        ("time=", "time = null: must be a mapping with keys duration, dt"),
    ],
)
def test_bad_values_name_key_value_and_rule(override, expected):
    assert expected in config_error(with_overrides(override))


def test_held_velocities_and_inverting_starts_that_are_allowed():
    """A velocity along held axes only, and a mirror start for the models that recover from one."""
    held = parse_scene(with_overrides("fixed=[{min: [0, 0, 0], max: [1, 1, 1], axes: [x, z], velocity: [1, 0, 2]}]"))
    assert held.fixed[0].velocity == (1.0, 0.0, 2.0)
    for model in ("neohookean", "corotated"):
        mirrored = parse_scene(with_overrides(f"material.model={model}",
                                              "initial_deformation.matrix=[[-1, 0, 0], [0, 1, 0], [0, 0, 1]]"))
        assert mirrored.initial_deformation.matrix[0] == (-1.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["mesh.size="], "mesh.size: required for shape 'box'"),
        (["mesh.element_size="], "mesh.element_size: required for shape 'box'"),
        (["mesh.shape=sphere", "mesh.size="], "mesh.radius: required for shape 'sphere'"),
        (["mesh.shape=cylinder", "mesh.size=", "mesh.radius=0.1"],
         "mesh.length: required for shape 'cylinder'"),
        (["mesh.shape=file", "mesh.size="], "mesh.file: required for shape 'file'"),
        (["mesh.shape=sphere", "mesh.size=", "mesh.radius=1", "mesh.structured=true"],
         "mesh.structured = true: not used with shape 'sphere' (only with box)"),
        (["mesh.axis=z"], "mesh.axis = 'z': not used with shape 'box' (only with cylinder)"),
    ],
)
def test_shape_dependent_keys(overrides, expected):
    assert expected in config_error(with_overrides(*overrides))


def test_cylinder_and_sphere_are_valid():
    cylinder = parse_scene(
        with_overrides(
            "mesh={shape: cylinder, radius: 0.05, length: 1, axis: z, element_size: 0.02}"
        )
    )
    assert (cylinder.mesh.radius, cylinder.mesh.length, cylinder.mesh.axis) == (0.05, 1.0, "z")
    sphere = parse_scene(with_overrides("mesh={shape: sphere, radius: 0.5, element_size: 0.1}"))
    assert sphere.mesh.radius == 0.5


def test_missing_required_section_and_key():
    data = {"mesh": MINIMAL["mesh"]}
    assert config_error(data) == "material: required section missing"
    data = copy.deepcopy(MINIMAL)
    del data["material"]["density"]
    assert "material.density: required key missing" in config_error(data)


def test_unknown_key_suggests_close_name():
    message = config_error(with_overrides("material.youngs_modulas=1e8"))
    assert message == (
        "material.youngs_modulas: unknown key; did you mean 'youngs_modulus'? "
        "(allowed: model, youngs_modulus, poissons_ratio, density)"
    )
    message = config_error(with_overrides("gravty=[0, 0, -1]"))
    assert message.startswith("gravty: unknown section; did you mean 'gravity'?")
    assert "fixed[0].axis: unknown key; did you mean 'axes'?" in config_error(
        with_overrides("fixed=[{min: [0, 0, 0], max: [1, 1, 1], axis: [x]}]")
    )
    assert "did you mean" not in config_error(with_overrides("ground.zzzzzz=1"))


def test_a_top_level_key_inside_a_section_is_pointed_to():
    """``material.damping``: close to no material key, so no suggestion was made."""
    assert config_error(with_overrides("material.damping=5")) == (
        "material.damping: unknown key; 'damping' is a top-level key, not one of this section "
        "(allowed: model, youngs_modulus, poissons_ratio, density)")
    assert "'gravity' is a top-level key" in config_error(with_overrides("time.gravity=[0, 0, -1]"))


@pytest.mark.parametrize("value", ["yes", "true", "off"])
def test_booleans_rejected_for_numbers(value):
    assert f"material.density = {'false' if value == 'off' else 'true'}: must be a number" in (
        config_error(with_overrides(f"material.density={value}"))
    )
    assert "gravity = [0, 0, " in config_error(with_overrides(f"gravity=[0, 0, {value}]"))


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf", "1e400"])
def test_non_finite_rejected(value):
    message = config_error(with_overrides(f"material.youngs_modulus={value}"))
    assert message.startswith("material.youngs_modulus = ")
    assert "must be a finite number" in message
    assert "must be a finite number" in config_error(with_overrides(f"gravity=[0, 0, {value}]"))
    assert "time.dt = " in config_error(with_overrides(f"time.dt={value}"))
    assert "ground.height = " in config_error(with_overrides(f"ground.height={value}"))


def test_several_problems_joined_on_one_line():
    message = config_error(with_overrides("damping=-1", "time.dt=0"))
    assert "damping = -1" in message and "time.dt = 0" in message and "; " in message


def test_parse_scene_rejects_non_mapping():
    assert "must be a mapping with sections mesh, material" in config_error([MINIMAL])


# ---------------------------------------------------------------------------------------------
# Files


@pytest.mark.parametrize("text, got", [("- mesh\n", "['mesh']"), ("42\n", "42"), ("", "empty")])
def test_non_mapping_yaml_file(tmp_path, text, got):
    with pytest.raises(ConfigError, match="must be a mapping with sections mesh, material") as info:
        load_scene(write(tmp_path, text))
    assert got in str(info.value)


def test_yaml_syntax_error_is_one_line_with_line_number(tmp_path):
    path = write(tmp_path, MINIMAL_YAML + "output: {path: [out.h5\ntime: {}\n")
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    message = str(info.value)
    assert "\n" not in message
    assert str(path) in message
    assert "line 11" in message


def test_duplicate_yaml_key_is_an_error(tmp_path):
    with pytest.raises(ConfigError, match="line 10, column 1: .*duplicate key 'material'"):
        load_scene(write(tmp_path, MINIMAL_YAML + "material: {}\n"))


def test_missing_scene_file(tmp_path):
    with pytest.raises(ConfigError, match="scene file not found"):
        load_scene(tmp_path / "nope.yaml")


def test_mesh_file_resolved_relative_to_scene_file(tmp_path, monkeypatch):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "beam.msh").write_text("")
    scene_dir = tmp_path / "scenes"
    scene_dir.mkdir()
    text = MINIMAL_YAML.replace(
        "  shape: box\n  size: [1, 0.1, 0.1]\n", "  shape: file\n  file: ../meshes/beam.msh\n"
    )
    monkeypatch.chdir(tmp_path)  # the working directory must not matter
    scene = load_scene(write(scene_dir, text))
    assert scene.mesh.file == str(tmp_path / "meshes" / "beam.msh")
    assert scene.mesh.element_size == 0.02  # allowed, unused, for file meshes


def test_missing_mesh_file_names_key_value_and_place(tmp_path):
    text = MINIMAL_YAML.replace(
        "  shape: box\n  size: [1, 0.1, 0.1]\n", "  shape: file\n  file: gone.msh\n"
    )
    with pytest.raises(ConfigError) as info:
        load_scene(write(tmp_path, text))
    message = str(info.value)
    assert message.startswith("mesh.file = 'gone.msh': mesh file not found")
    assert str(tmp_path / "gone.msh") in message


def test_mesh_file_that_is_a_directory(tmp_path):
    (tmp_path / "dir.msh").mkdir()
    data = with_overrides("mesh={shape: file, file: dir.msh}")
    assert "mesh.file = 'dir.msh': mesh file is not a file" in config_error(data, base_dir=tmp_path)


# ---------------------------------------------------------------------------------------------
# Overrides


def test_overrides_change_and_add_values(tmp_path):
    scene = load_scene(
        write(tmp_path, MINIMAL_YAML),
        overrides=[
            "material.youngs_modulus=2e8",
            "material.model = neohookean",
            "ground.stiffness=1e5",
            "output.fields=[energy]",
            "time.dt=auto",
        ],
    )
    assert scene.material.youngs_modulus == 2.0e8
    assert scene.material.model == "neohookean"
    assert scene.ground == Ground(stiffness=1.0e5)
    assert scene.output.fields == ("energy",)


def test_override_errors_name_the_override(tmp_path):
    path = write(tmp_path, MINIMAL_YAML)
    for override, expected in [
        ("material.density", "override 'material.density': must look like key.path=value"),
        ("mesh.size.x=1", "override 'mesh.size.x=1': mesh.size is a list, so it has no key 'x'; name an item, "
                          "as mesh.size[0]"),
        ("mesh.shape.x=1", "override 'mesh.shape.x=1': mesh.shape is 'box', not a mapping, so it has no key 'x'"),
        ("fixed[0].min=[0, 0, 0]", "override 'fixed[0].min=[0, 0, 0]': fixed has no items, so no fixed[0]; give "
                                   "the whole list as fixed"),
        ("mesh[0]=1", "override 'mesh[0]=1': mesh is {'shape': 'box'"),
        ("fixed[-1].min=1", "override 'fixed[-1].min=1': 'fixed[-1]' is no key; a list item is named by its "
                            "number from 0"),
        ("material..density=1", "override 'material..density=1': the key path"),
        ("gravity=[0, 0", "override 'gravity=[0, 0': invalid YAML"),
    ]:
        with pytest.raises(ConfigError) as info:
            load_scene(path, overrides=[override])
        assert str(info.value).startswith(expected)
    with pytest.raises(ConfigError, match="material.denisty: unknown key; did you mean 'density'"):
        load_scene(path, overrides=["material.denisty=3"])


def test_overrides_name_list_items_as_the_errors_do():
    data = apply_overrides(MINIMAL, ["fixed=[{min: [0, 0, 0], max: [1, 1, 1]}, {min: [2, 2, 2], max: [3, 3, 3]}]",
                                     "fixed[1].max=[4, 4, 4]", "fixed[1].velocity=[0, 0, 1]", "mesh.size[2]=0.2"])
    scene = parse_scene(data)
    assert scene.fixed[0].max == (1.0, 1.0, 1.0) and scene.fixed[1].max == (4.0, 4.0, 4.0)
    assert scene.fixed[1].velocity == (0.0, 0.0, 1.0) and scene.mesh.size == (1.0, 0.1, 0.2)
    with pytest.raises(ConfigError, match=r"^override 'fixed\[2\].min=1': fixed has 2 items, so no fixed\[2\]$"):
        apply_overrides(data, ["fixed[2].min=1"])


def test_overrides_do_not_touch_the_input():
    before = copy.deepcopy(MINIMAL)
    apply_overrides(MINIMAL, ["material.density=1", "ground.height=2", "mesh.size[0]=3"])
    assert MINIMAL == before


# ---------------------------------------------------------------------------------------------
# Round trip


def test_scene_to_yaml_round_trip(tmp_path):
    (tmp_path / "m.msh").write_text("")
    data = with_overrides(
        "mesh={shape: file, file: m.msh}",
        "ground={height: -0.5, friction: 0.4}",
        "fixed=[{min: [0, 0, 0], max: [0, 1, 1], axes: [x, z], velocity: [0.1, 0, 0]}]",
        "tractions=[{min: [1, 0, 0], max: [1, 1, 1], traction: [1e4, 0, -2.5e-3]}]",
        "initial_deformation.matrix=[[1.1, 0, 0], [0, 1, 0.2], [0, 0, 0.9]]",
        "angular_velocity=[0, 0, 3.14159]",
        "time.dt=1e-5",
        "output={path: runs/a.h5, fields: [velocities, energy]}",
    )
    scene = parse_scene(data, base_dir=tmp_path)
    text = scene_to_yaml(scene)
    assert parse_scene(yaml.load(text, Loader=SceneLoader)) == scene
    assert parse_scene(yaml.safe_load(text)) == scene
    minimal = parse_scene(MINIMAL)
    assert parse_scene(yaml.load(scene_to_yaml(minimal), Loader=SceneLoader)) == minimal
    assert "element_size: 0.02" in scene_to_yaml(minimal)
