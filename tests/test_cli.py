"""The ``softsim`` command line: options, the summary line, bad input, ``softsim mesh``."""

import io
import re
import subprocess
import sys
from pathlib import Path

import h5py
import meshio
import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from softsim.cli import run as run_module
from softsim.cli.main import cli
from softsim.config import SceneLoader, load_scene, parse_scene

# A 0.3 x 0.1 x 0.1 m bar of 6 x 2 x 2 hex cells = 120 tets, 63 vertices; 4 frames.
SCENE = """\
mesh:
  shape: box
  size: [0.3, 0.1, 0.1]
  origin: [0.0, -0.05, -0.05]
  element_size: 0.05
  structured: true
material:
  model: stvk
  youngs_modulus: 1.0e6
  poissons_ratio: 0.3
  density: 1000.0
fixed:
  - {min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}
time:
  duration: 0.003
output:
  path: out.h5
  frame_interval: 0.001
"""
TETS = 120
BOX_MESH = ("  shape: box\n  size: [0.3, 0.1, 0.1]\n  origin: [0.0, -0.05, -0.05]\n"
            "  element_size: 0.05\n  structured: true\n")


def scene_with(*replacements, text=SCENE):
    """SCENE with each ``(old, new)`` text replacement applied (each ``old`` must occur)."""
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    return text


def invoke(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def error_lines(stderr):
    """The lines of ``stderr`` but for the notice of compiling (``cli.main.COMPILE_NOTICE``), which
    precedes an error found after a first compile when the cache is cold (a tangled mesh file is
    found by a compiled kernel)."""
    from softsim.cli.main import COMPILE_NOTICE

    return [line for line in stderr.splitlines() if COMPILE_NOTICE not in line]


def ok(*args):
    result = invoke(*args)
    assert result.exit_code == 0, (result.output, result.exception)
    return result


@pytest.fixture
def work(tmp_path, monkeypatch):
    """A scratch working directory (a relative output.path lands here)."""
    folder = tmp_path / "work"
    folder.mkdir()
    monkeypatch.chdir(folder)
    return folder


def write(folder, text, name="scene.yaml"):
    path = folder / name
    path.write_text(text)
    return path


def stored_config(path):
    with h5py.File(path) as f:
        return parse_scene(yaml.load(f.attrs["config"], Loader=SceneLoader))


# ---------------------------------------------------------------------------------------------
# Options


def test_output_path_from_the_scene_is_relative_to_the_working_directory(work, tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    ok("run", write(scenes, SCENE))
    assert (work / "out.h5").is_file() and (work / "out.xdmf").is_file()
    assert not (scenes / "out.h5").exists()
    with h5py.File(work / "out.h5") as f:
        assert f.attrs["status"] == "complete"


def test_the_run_line_names_the_safe_step_of_the_dt_asked_for(work):
    """``dt: auto`` runs at its safe step, below the stability limit; ``dt: exact`` at 0.9x the limit."""
    scene = write(work, SCENE)
    auto = ok("run", scene, "-o", "auto.h5")
    assert re.search(r"safe step \S+ s \(dt: auto's, below the stability limit\)", auto.stderr), auto.stderr
    exact = ok("run", scene, "-o", "exact.h5", "--set", "time.dt=exact")
    assert re.search(r"safe step \S+ s \(0.9 x the stability limit\)", exact.stderr), exact.stderr


def test_dash_o_overrides_output_path(work):
    ok("run", write(work, SCENE), "-o", "other.h5")
    assert sorted(p.name for p in work.iterdir()) == ["other.h5", "other.xdmf", "scene.yaml"]
    assert stored_config(work / "other.h5").output.path == "other.h5"


def test_set_changes_the_run_and_the_stored_config(work):
    scene = write(work, SCENE)
    ok("run", scene, "-o", "base.h5")
    ok("run", scene, "-o", "stiff.h5", "--set", "material.youngs_modulus=2e8", "--set", "damping=0.5")
    base, stiff = stored_config(work / "base.h5"), stored_config(work / "stiff.h5")
    assert base.material.youngs_modulus == 1.0e6
    assert stiff.material.youngs_modulus == 2.0e8 and isinstance(stiff.material.youngs_modulus, float)
    assert stiff.damping == 0.5
    expected = load_scene(scene, ["material.youngs_modulus=2e8", "damping=0.5", "output.path=stiff.h5"])
    assert stiff == expected
    with h5py.File(work / "base.h5") as f, h5py.File(work / "stiff.h5") as g:
        assert g.attrs["dt"] < f.attrs["dt"]      # stiffer material: smaller stable step
        assert g.attrs["steps"] > f.attrs["steps"]


def test_exponent_numbers_without_a_dot_are_numbers(work):
    text = scene_with(("youngs_modulus: 1.0e6", "youngs_modulus: 2.0e11"),
                      ("density: 1000.0", "density: 8e3"),
                      ("duration: 0.003", "duration: 2e-5"),
                      ("frame_interval: 0.001", "frame_interval: 1e-5"))
    text += "ground: {height: -1, stiffness: 1e6}\n"
    ok("run", write(work, text), "-o", "steel.h5")
    scene = stored_config(work / "steel.h5")
    assert scene.material.youngs_modulus == 2.0e11
    assert scene.material.density == 8000.0
    assert scene.time.duration == 2e-5 and scene.output.frame_interval == 1e-5
    assert scene.ground.stiffness == 1e6
    with h5py.File(work / "steel.h5") as f:
        np.testing.assert_allclose(f["frames/time"][:], [0.0, 1e-5, 2e-5], rtol=0, atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Summary line and progress bar


def test_summary_line(work):
    result = ok("run", write(work, SCENE), "-o", "run.h5")
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1, result.stdout
    line = lines[0]
    with h5py.File(work / "run.h5") as f:
        steps, dt, wall = int(f.attrs["steps"]), float(f.attrs["dt"]), float(f.attrs["wall_time_s"])
    assert re.search(rf"\b{steps} steps\b", line), line
    shown_dt = float(re.search(r"dt ([0-9.eE+-]+) s", line).group(1))
    assert shown_dt == pytest.approx(dt, rel=1e-3)
    shown_wall = float(re.search(r"wall ([0-9.]+) s", line).group(1))
    assert 0 < shown_wall < 60
    assert shown_wall == pytest.approx(wall, abs=0.5)
    rate = re.search(r"([0-9.eE+-]+) (M )?tet-steps/s", line)
    assert rate, line
    shown_rate = float(rate.group(1)) * (1e6 if rate.group(2) else 1.0)
    compiling = re.search(r"\(([0-9.]+) s of it compiling the kernels", line)
    shown_compiling = float(compiling.group(1)) if compiling else 0.0
    assert 0.0 <= shown_compiling <= shown_wall
    assert shown_rate == pytest.approx(TETS * steps / (shown_wall - shown_compiling), rel=0.5)


def test_no_progress_bar_when_stderr_is_not_a_terminal(work):
    result = ok("run", write(work, SCENE), "-o", "run.h5")
    assert "\r" not in result.stderr and "%|" not in result.stderr and "step/s" not in result.stderr
    assert "\r" not in result.stdout


def test_no_progress_bar_on_a_pipe(monkeypatch):
    monkeypatch.setattr(run_module.sys, "stderr", io.StringIO())
    assert run_module._progress_bar(100) is None


def test_progress_bar_on_a_terminal(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(run_module.sys, "stderr", terminal)
    bar = run_module._progress_bar(40)
    assert bar is not None
    bar.update(40)
    bar.refresh()
    assert "40/40" in terminal.getvalue() and "step" in terminal.getvalue()
    bar.close()


# ---------------------------------------------------------------------------------------------
# Bad input: one line on stderr naming key, value and what is allowed; non-zero exit; no file


def _mesh_file(folder, name, points, cells):
    meshio.write(folder / name, meshio.Mesh(np.asarray(points, float), cells))


UNIT_TET = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]


def _file_scene(name):
    return scene_with((BOX_MESH, f"  shape: file\n  file: {name}\n"))


def _no_tets(folder):
    _mesh_file(folder, "surface.vtu", UNIT_TET, [("triangle", [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])])
    return _file_scene("surface.vtu")


def _flat_tet(folder):
    points = UNIT_TET + [[1, 1, 0]]                 # vertex 4 lies in the plane z = 0 of 0, 1, 2
    _mesh_file(folder, "flat.vtu", points, [("tetra", [[0, 1, 2, 3], [0, 1, 2, 4]])])
    return _file_scene("flat.vtu")


def _tangled(folder):
    points = UNIT_TET + [[0.2, 0.2, 0.5]]           # vertex 4 on the same side of face 0-1-2 as 3
    _mesh_file(folder, "tangled.vtu", points, [("tetra", [[0, 1, 2, 3], [0, 1, 2, 4]])])
    return _file_scene("tangled.vtu")


def _garbage(name, content):
    def setup(folder):
        (folder / name).write_text(content)
        return _file_scene(name)
    return setup


def _hexes(folder):
    cube = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
    _mesh_file(folder, "hex.vtu", cube, [("hexahedron", [list(range(8))])])
    return _file_scene("hex.vtu")


BAD_INPUTS = [
    # id, scene text (or setup(folder) -> text, or None: no scene file), extra args, expected parts
    ("unknown-key", scene_with(("density: 1000.0", "densty: 1000.0")), [],
     ["material.densty", "unknown key", "density"]),
    ("unknown-section", SCENE + "gravty: [0, 0, -9.81]\n", [], ["gravty", "unknown", "'gravity'"]),
    ("unknown-key-by-set", SCENE, ["--set", "material.poisson=0.3"],
     ["material.poisson", "unknown key", "poissons_ratio"]),
    ("string-for-number", scene_with(("density: 1000.0", "density: heavy")), [],
     ["material.density", "heavy", "must be a number"]),
    ("yes-for-number", scene_with(("youngs_modulus: 1.0e6", "youngs_modulus: yes")), [],
     ["material.youngs_modulus", "true", "must be a number"]),
    ("quoted-number", scene_with(("density: 1000.0", "density: '1000'")), [],
     ["material.density", "'1000'", "must be a number"]),
    ("unknown-model", scene_with(("model: stvk", "model: rubber")), [],
     ["material.model", "rubber", "neohookean"]),
    ("poisson-0.5", scene_with(("poissons_ratio: 0.3", "poissons_ratio: 0.5")), [],
     ["material.poissons_ratio", "0.5", "greater than -1 and less than 0.5"]),
    ("poisson--1.2", scene_with(("poissons_ratio: 0.3", "poissons_ratio: -1.2")), [],
     ["material.poissons_ratio", "-1.2", "greater than -1 and less than 0.5"]),
    ("youngs-zero", scene_with(("youngs_modulus: 1.0e6", "youngs_modulus: 0")), [],
     ["material.youngs_modulus", "0", "greater than 0"]),
    ("youngs-negative", SCENE, ["--set", "material.youngs_modulus=-2e8"],
     ["material.youngs_modulus", "-200000000.0", "greater than 0"]),
    ("density-zero", scene_with(("density: 1000.0", "density: 0.0")), [],
     ["material.density", "0.0", "at least 0.001"]),
    ("density-negative", scene_with(("density: 1000.0", "density: -1000")), [],
     ["material.density", "-1000", "at least 0.001"]),
    ("duration-zero", scene_with(("duration: 0.003", "duration: 0")), [],
     ["time.duration", "0", "greater than 0"]),
    ("duration-negative", SCENE, ["--set", "time.duration=-1"], ["time.duration", "-1", "greater than 0"]),
    ("element-size-zero", scene_with(("element_size: 0.05", "element_size: 0")), [],
     ["mesh.element_size", "0", "greater than 0"]),
    ("element-size-negative", scene_with(("element_size: 0.05", "element_size: -0.05")), [],
     ["mesh.element_size", "-0.05", "greater than 0"]),
    ("nan", scene_with(("youngs_modulus: 1.0e6", "youngs_modulus: .nan")), [],
     ["material.youngs_modulus", "nan", "finite"]),
    ("inf", scene_with(("density: 1000.0", "density: .inf")), [], ["material.density", "inf", "finite"]),
    ("inf-by-set", SCENE, ["--set", "time.duration=.inf"], ["time.duration", "inf", "finite"]),
    ("overflow-to-inf", scene_with(("density: 1000.0", "density: 1e999")), [],
     ["material.density", "finite"]),
    ("nan-in-vector", SCENE + "gravity: [0, 0, .nan]\n", [], ["gravity", "finite"]),
    ("missing-mesh-file", _file_scene("nowhere.msh"), [], ["mesh.file", "nowhere.msh", "not found"]),
    ("mesh-file-is-text", _garbage("notes.vtu", "this is not a mesh\n"), [],
     ["mesh.file", "notes.vtu", "cannot be read as a mesh"]),
    ("mesh-file-unknown-format", _garbage("beam.txt", "1 2 3\n"), [],
     ["mesh.file", "beam.txt", "cannot be read as a mesh"]),
    ("mesh-file-empty", _garbage("empty.msh", ""), [], ["mesh.file", "empty.msh", "cannot be read"]),
    ("mesh-without-tets", _no_tets, [], ["mesh.file", "surface.vtu", "no tetrahedra", "triangle"]),
    ("mesh-with-hexes", _hexes, [], ["mesh.file", "hex.vtu", "hexahedron", "tetrahedra only"]),
    ("zero-volume-tet", _flat_tet, [], ["flat.vtu", "degenerate", "volume", "allowed"]),
    ("tangled-mesh", _tangled, [], ["tangled.vtu", "tangled", "same side"]),
    ("list-not-mapping", "- mesh\n- material\n", [], ["must be a mapping", "mesh", "material"]),
    ("scalar-not-mapping", "42\n", [], ["must be a mapping", "42"]),
    ("empty-scene", "", [], ["must be a mapping", "empty"]),
    ("yaml-syntax-error", "mesh: {shape: box, size: [1, 2\nmaterial: {}\n", [],
     ["scene.yaml", "invalid YAML", "line"]),
    ("duplicate-key", SCENE + "damping: 1\ndamping: 2\n", [], ["scene.yaml", "duplicate key", "damping"]),
    ("missing-section", scene_with(("material:\n", "materials:\n")), [], ["material", "materials"]),
    ("missing-scene-file", None, [], ["scene file not found", "scene.yaml"]),
    ("output-folder-missing", SCENE, ["-o", "no/such/folder/out.h5"], ["no/such/folder/out.h5", "does not exist"]),
    ("output-folder-missing-in-scene", scene_with(("path: out.h5", "path: nowhere/out.h5")), [],
     ["output.path", "nowhere/out.h5", "does not exist"]),
    ("output-is-a-folder", SCENE, ["-o", "."], ["'.'", "directory"]),
    ("output-named-like-the-xdmf", SCENE, ["-o", "run.xdmf"], ["run.xdmf", "XDMF", "out.h5"]),
    # HDF5 under another name was written silently
    ("output-not-an-hdf5-name", SCENE, ["-o", "out.txt"], ["output.path = 'out.txt'", ".h5 or .hdf5"]),
    ("output-named-like-vtu", SCENE, ["-o", "beam.vtu"], ["beam.vtu", ".h5 or .hdf5", "softsim export"]),
    ("output-without-suffix-in-scene", scene_with(("path: out.h5", "path: results")), [],
     ["output.path = 'results'", ".h5 or .hdf5"]),
    # a folder that takes no new file (for root too): caught before meshing, not as a full disk
    ("output-folder-takes-no-file", SCENE, ["-o", "/proc/out.h5"], ["output.path = '/proc/out.h5'", "folder /proc"]),
    ("output-is-the-scene", SCENE, ["-o", "scene.yaml", "--overwrite"], ["scene.yaml", "the scene's own file"]),
    ("bad-set-syntax", SCENE, ["--set", "material.youngs_modulus"], ["material.youngs_modulus", "key.path=value"]),
    ("bad-dt", scene_with(("duration: 0.003", "duration: 0.003\n  dt: fast")), [],
     ["time.dt", "fast", "'auto', 'exact' or a positive number"]),
]


@pytest.mark.parametrize("case", BAD_INPUTS, ids=[case[0] for case in BAD_INPUTS])
def test_bad_input_gets_one_line_and_no_output(case, work, tmp_path):
    _, text, args, expected = case
    if callable(text):
        text = text(work)
    if text is not None:
        write(work, text)
    result = invoke("run", work / "scene.yaml", *args)
    assert result.exit_code != 0
    assert result.exit_code != 130
    # a handled error, not an exception escaping click (which a terminal shows as a traceback)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = error_lines(result.stderr)
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.output
    for part in expected:
        assert part in lines[0], (part, lines[0])
    assert result.stdout == ""
    left = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.suffix in (".h5", ".xdmf"))
    assert left == []


def test_bad_mesh_output_folder_is_one_line(work):
    result = invoke("mesh", write(work, SCENE), "-o", "no/such/folder/mesh.vtu")
    assert result.exit_code != 0
    assert len(result.stderr.splitlines()) == 1, result.stderr
    assert "no/such/folder/mesh.vtu" in result.stderr


def test_a_bug_is_one_line_naming_the_command_that_shows_its_traceback(work, monkeypatch):
    """An exception that is no ``SoftsimError`` (a bug) prints one line that says how to see the
    traceback, ``-vv`` placed before the command (``softsim run x.yaml -vv`` is refused by click);
    with ``-vv`` the exception goes on to the caller."""
    def broken(*args, **kwargs):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr(run_module, "load_scene", broken)
    scene = write(work, SCENE)
    result = invoke("run", scene)
    assert result.exit_code == 1
    assert error_lines(result.stderr) == [
        "Error: unexpected RuntimeError: boom (run 'softsim -vv run ...' for the traceback: -vv goes before the command)"]
    verbose = invoke("-vv", "run", scene)
    assert isinstance(verbose.exception, RuntimeError) and str(verbose.exception) == "boom\nsecond line"


def test_console_script_bad_input_is_one_line_without_traceback(tmp_path):
    """The installed ``softsim`` script, in a real process: the user's view of a bad scene."""
    script = Path(sys.executable).with_name("softsim")
    assert script.is_file(), script
    scene = write(tmp_path, scene_with(("density: 1000.0", "density: heavy")))
    done = subprocess.run([str(script), "run", str(scene)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode != 0
    assert "Traceback" not in done.stderr + done.stdout
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert "material.density" in lines[0] and "heavy" in lines[0] and "number" in lines[0]
    assert done.stdout == ""
    assert not list(tmp_path.glob("*.h5")) and not list(tmp_path.glob("*.xdmf"))


# ---------------------------------------------------------------------------------------------
# softsim mesh


def test_mesh_command_writes_a_readable_mesh(work):
    result = ok("mesh", write(work, SCENE), "-o", "bar.vtu")
    mesh = meshio.read(work / "bar.vtu")
    assert len(mesh.get_cells_type("tetra")) == TETS
    assert len(mesh.points) == 63
    tets = mesh.get_cells_type("tetra")
    X = mesh.points[tets]
    assert (np.linalg.det(X[:, 1:] - X[:, :1]) > 0).all()
    assert "bar.vtu" in result.stdout and str(TETS) in result.stdout
    assert not list(work.glob("*.h5"))


def test_mesh_command_honours_set(work):
    ok("mesh", write(work, SCENE), "-o", "fine.vtu", "--set", "mesh.element_size=0.025")
    assert len(meshio.read(work / "fine.vtu").get_cells_type("tetra")) == 12 * 4 * 4 * 5


def test_mesh_command_reports_quality(work):
    result = ok("mesh", write(work, SCENE), "-o", "bar.vtu")
    assert "dihedral" in result.stderr and f"{TETS} tets" in result.stderr


def test_a_command_that_compiles_says_so_once(work, monkeypatch):
    """A command that compiles kernels (as with a fresh cache: here two functions made anew for
    each call, compiled inside ``softsim mesh``) says so once, before it compiles; one that
    compiles nothing does not, and -q silences it."""
    import numba

    from softsim.cli import mesh as mesh_module
    from softsim.cli.main import COMPILE_NOTICE

    build_mesh = mesh_module.build_mesh

    def compiling_build_mesh(config):
        doubled = numba.njit(lambda a: 2.0 * a)
        tripled = numba.njit(lambda a: 3.0 * a)
        assert doubled(1.0) + tripled(1.0) == 5.0
        return build_mesh(config)

    scene = write(work, SCENE)
    monkeypatch.setattr(mesh_module, "build_mesh", compiling_build_mesh)
    compiled = ok("mesh", scene, "-o", "first.vtu").stderr
    assert compiled.count(COMPILE_NOTICE) == 1
    assert compiled.index(COMPILE_NOTICE) < compiled.index("dihedral")
    assert COMPILE_NOTICE not in ok("-q", "mesh", scene, "-o", "quiet.vtu").stderr
    monkeypatch.setattr(mesh_module, "build_mesh", build_mesh)
    ok("mesh", scene, "-o", "warm.vtu")
    warm = ok("mesh", scene, "-o", "warm.vtu", "--overwrite").stderr
    assert COMPILE_NOTICE not in warm and "dihedral" in warm


def test_a_line_logged_under_the_progress_bar_goes_above_it(monkeypatch):
    """A library message while ``softsim run`` shows its bar is written by tqdm, which clears the
    bar, writes the line and draws the bar again, not onto the end of the bar's line."""
    import logging

    from softsim.cli.main import _EchoHandler

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    logger = logging.getLogger("softsim.test_cli.echo")
    logger.addHandler(_EchoHandler())
    logger.propagate = False
    bar = run_module._progress_bar(40)
    bar.update(10)
    bar.refresh()
    logger.warning("something")
    bar.close()
    logger.handlers.clear()
    assert "warning: something\n" in terminal.getvalue()
    lines = terminal.getvalue().split("\n")
    assert any(line.split("\r")[-1].strip() == "warning: something" for line in lines), terminal.getvalue()


def test_a_given_dt_above_the_stable_step_is_substepped_refused_or_allowed(work):
    """dt_policy: substep (default) splits the step and says so; refuse gives one line and no
    file; allow uses it with a warning (the guard is then the safety net)."""
    args = ("--set", "time.dt=0.01", "--set", "time.duration=0.02", "--set", "output.frame_interval=0.01")
    substep = ok("run", write(work, SCENE), "-o", "sub.h5", *args)
    assert "sub-steps" in substep.stderr and "warning" not in substep.stderr
    with h5py.File(work / "sub.h5") as f:
        assert f.attrs["dt"] < 0.01 and 0.01 / f.attrs["dt"] == pytest.approx(round(0.01 / f.attrs["dt"]))

    refused = invoke("run", write(work, SCENE), "-o", "refused.h5", *args, "--set", "time.dt_policy=refuse")
    assert refused.exit_code != 0
    assert len(error_lines(refused.stderr)) == 1 and "time.dt = 0.01" in refused.stderr
    assert "above the safe step" in refused.stderr and not (work / "refused.h5").exists()

    allowed = invoke("run", write(work, SCENE), "-o", "allowed.h5", *args, "--set", "time.dt_policy=allow")
    warning = [line for line in allowed.stderr.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1 and "time.dt = 0.01" in warning[0], allowed.stderr
    auto = ok("run", write(work, SCENE), "-o", "auto.h5")
    assert "warning" not in auto.stderr


def test_ctrl_c_while_the_commands_load_is_one_line_and_exit_130():
    """The console script (``softsim.cli.launch``) loads the commands inside a handler: a Ctrl-C in
    that half second printed a 20-line traceback from inside Numba's imports.  The Ctrl-C is made
    to land there by an ``__import__`` that raises it when numba is imported."""
    code = ("import builtins, sys\n"
            "real = builtins.__import__\n"
            "def interrupted(name, *args, **kwargs):\n"
            "    if name == 'numba':\n"
            "        raise KeyboardInterrupt\n"
            "    return real(name, *args, **kwargs)\n"
            "builtins.__import__ = interrupted\n"
            "sys.argv = ['softsim', 'run', 'scene.yaml']\n"
            "from softsim.cli.launch import main\n"
            "main()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stderr, done.stdout) == (130, "softsim: interrupted\n", "")


@pytest.mark.parametrize("args, expected", [
    (["run", "{scene}", "--resume", "--overwrite"],
     "Error: --resume and --overwrite exclude each other (see 'softsim run --help')"),
    (["run"], "Error: Missing argument 'SCENE'. (see 'softsim run --help')"),
    (["run", "{scene}", "--set"], "Error: Option '--set' requires an argument. (see 'softsim run --help')"),
    (["render", "x.h5", "-o", "x.png", "--view", "top"], "Error: Invalid value for '--view': 'top' is not one of "),
    (["nosuch"], "Error: No such command 'nosuch'. (see 'softsim --help')"),
    (["--bad"], "Error: No such option '--bad'. (see 'softsim --help')"),
])
def test_a_usage_error_is_one_line_naming_the_help(work, args, expected):
    """click's usage errors (usage, a hint, the error: three lines) come as one line, exit code 2."""
    result = CliRunner().invoke(cli, [a.format(scene=write(work, SCENE)) for a in args], prog_name="softsim")
    assert result.exit_code == 2
    assert len(result.stderr.splitlines()) == 1 and result.stderr.startswith(expected), result.stderr


def test_no_command_shows_the_help():
    result = invoke()
    assert "Commands:" in result.output and "Error" not in result.output


def test_a_body_held_everywhere_has_no_step_limit_and_runs(work):
    scene = write(work, scene_with(("{min: [-1.0e-6, -1, -1], max: [1.0e-6, 1, 1]}", "{min: [-1, -1, -1], max: [1, 1, 1]}")))
    result = invoke("run", scene, "-o", work / "held.h5")
    assert result.exit_code == 0, result.stderr
    assert "no step limit (nothing moves but held vertices)" in result.stderr and " inf " not in result.stderr
