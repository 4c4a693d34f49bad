"""Looking at results: softsim info / export / plot / render on small simulated runs.

Two runs are shared by the module: a rubber cube falling freely (40 tets) and a clamped bar
sagging under gravity (120 tets), whose bending stress theory puts at the clamped root.
"""

import json

import h5py
import meshio
import numpy as np
import pytest
from click.testing import CliRunner

from softsim.cli.main import cli
from softsim.config import parse_scene
from softsim.errors import MissingDependencyError
from softsim.simulation import prepare, simulate
from softsim.viz.render import Renderer, boundary_faces
from softsim.viz.results import ResultsError, open_results
from conftest import scene_dict

BAR_FIELDS = ["velocities", "energy", "stress", "strain", "pressure", "von_mises", "J", "speed"]


def run_cli(*args, ok=True):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    if ok:
        assert result.exit_code == 0, (result.output, result.exception)
    return result


@pytest.fixture(scope="module")
def cube(tmp_path_factory):
    """A 0.2 m cube falling from rest for 0.1 s (it drops 4.9 cm), 3 frames, no extra fields."""
    folder = tmp_path_factory.mktemp("cube")
    scene = parse_scene(scene_dict(time={"duration": 0.1}, output={"frame_interval": 0.05}), base_dir=folder)
    path = folder / "cube.h5"
    simulate(prepare(scene), path)
    return path


@pytest.fixture(scope="module")
def bar(tmp_path_factory):
    """A 0.3 m bar clamped at x = 0 sagging under gravity for 0.08 s (near its largest sag)."""
    folder = tmp_path_factory.mktemp("bar")
    scene = parse_scene(scene_dict(
        mesh={"size": [0.3, 0.1, 0.1], "origin": [0.0, -0.05, -0.05], "element_size": 0.05},
        material={"youngs_modulus": 1.0e6},
        fixed=[{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}],
        time={"duration": 0.08}, output={"frame_interval": 0.04, "fields": BAR_FIELDS}), base_dir=folder)
    path = folder / "bar.h5"
    simulate(prepare(scene), path)
    return path


def object_mask(image):
    """Pixels that are not the white background (the colour bar and text are cut off)."""
    height, width, _ = image.shape
    mask = np.any(image < 235, axis=2)
    mask[:, int(0.78 * width):] = False       # colour bar and its labels
    mask[: int(0.12 * height), :] = False     # time stamp
    return mask


# ---------------------------------------------------------------------------------------------
# render


def test_rendered_frames_show_the_object_and_it_falls(cube):
    with open_results(cube) as results:
        renderer = Renderer(results, [0, 2], size=(320, 240), view="xz")
        try:
            first, last = renderer.image(0), renderer.image(2)
        finally:
            renderer.close()
    assert first.shape == (240, 320, 3)
    for image in (first, last):
        mask = object_mask(image)
        assert mask.mean() > 0.03                      # the cube is there ...
        assert image[mask].std() > 5                   # ... shaded, not a flat blot
    rows = np.nonzero(object_mask(first))[0].mean(), np.nonzero(object_mask(last))[0].mean()
    assert rows[1] > rows[0] + 3                       # and lower in the picture after falling
    # Camera and colours are fixed: the static parts of the picture (the colour bar) agree.
    np.testing.assert_array_equal(first[:, int(0.8 * 320):int(0.84 * 320)][40:200],
                                  last[:, int(0.8 * 320):int(0.84 * 320)][40:200])


def test_a_scene_with_a_ground_shows_it_and_the_shadow_below_the_body(cube):
    with open_results(cube) as results:
        results.scene = {**results.scene, "ground": {"height": -0.3}}      # 0.3 m below the cube
        renderer = Renderer(results, [0], size=(320, 240), view="oblique")
        try:
            image = renderer.image(0).astype(int)
        finally:
            renderer.close()
    greyish = image.max(axis=2) - image.min(axis=2) < 25
    grey = greyish & (image.mean(axis=2) > 160) & (image.mean(axis=2) < 235)        # the lit ground
    shadow = greyish & (image.mean(axis=2) > 90) & (image.mean(axis=2) <= 160)      # darker ground
    body = ~greyish                                                                 # coloured by the field
    body[:, int(0.78 * 320):] = False
    body[: int(0.12 * 240), :] = False
    assert grey.mean() > 0.1 and shadow.mean() > 0.005 and body.mean() > 0.02
    assert np.nonzero(shadow)[0].mean() > np.nonzero(body)[0].mean() + 20     # the shadow lies lower


def test_von_mises_picture_is_hottest_at_the_clamped_root(bar):
    """Bending moment, hence von Mises stress, is largest at the clamp (x = 0, left in the xz view);
    viridis runs from dark purple (low: little green) to yellow (high: much green)."""
    with open_results(bar) as results:
        values = results.field("von_mises", -1)
        centroid_x = results.frame_points(-1)[results.tets].mean(axis=1)[:, 0]
        assert values[centroid_x < 0.1].mean() > 3 * values[centroid_x > 0.2].mean()   # the data says so too
        renderer = Renderer(results, [results.frame_count - 1], field="von_mises", size=(480, 320), view="xz",
                            show_edges=False)
        try:
            image = renderer.image(results.frame_count - 1).astype(float)
        finally:
            renderer.close()
    mask = object_mask(image)
    columns = np.nonzero(mask.any(axis=0))[0]
    left, right = columns.min(), columns.max()
    third = (right - left) // 3
    green = image[..., 1]
    root = green[:, left:left + third][mask[:, left:left + third]].mean()
    tip = green[:, right - third:right][mask[:, right - third:right]].mean()
    assert root > tip + 40


def test_render_cli_writes_png_and_gif(bar, tmp_path):
    import imageio.v3 as iio

    png, gif = tmp_path / "bar.png", tmp_path / "bar.gif"
    run_cli("render", bar, "-o", png, "--field", "stress_xx", "--frame", "1", "--size", "200x150")
    assert iio.imread(png).shape[:2] == (150, 200)
    run_cli("render", bar, "-o", gif, "--frames", "0:3", "--size", "160x120")
    frames = iio.imread(gif, index=None)
    assert frames.shape[0] == 3 and frames.shape[1:3] == (120, 160)
    assert not np.array_equal(frames[0], frames[-1])


def test_render_cli_writes_mp4(bar, tmp_path):
    import imageio.v3 as iio

    mp4 = tmp_path / "bar.mp4"
    result = run_cli("render", bar, "-o", mp4, "--size", "170x130", "--fps", "5")
    frames = iio.imread(mp4, index=None, plugin="FFMPEG")
    assert frames.shape[0] == 3 and frames.shape[1:3] == (128, 160)     # sides cut to multiples of 16, and said so
    assert "the .mp4 is 160x128 pixels, not 170x130: video codecs take sides that are multiples of 16" in result.output


def test_render_refuses_a_gif_faster_than_its_players_play(bar, tmp_path):
    gif = tmp_path / "bar.gif"
    result = run_cli("render", bar, "-o", gif, "--fps", "80", ok=False)
    assert result.exit_code == 1 and not gif.exists()
    assert result.output.strip().splitlines()[-1].startswith("Error: --fps = 80: a .gif plays at most 50 frames per "
                                                             "second")
    run_cli("render", bar, "-o", gif, "--fps", "50", "--frames", "0:2", "--size", "64x48")


def test_boundary_faces_of_a_cube_are_outward_and_cover_its_surface():
    from softsim.mesh.generate import structured_box

    points, tets = structured_box((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 0.5)
    faces, parent = boundary_faces(tets)
    assert len(faces) == 6 * 2 * 2 * 2            # 4 cells per side, 2 triangles each
    p = points[faces]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    outward = p.mean(axis=1) - 0.5
    assert np.all(np.einsum("ij,ij->i", normals, outward) > 0)
    assert np.all(np.isin(faces, tets[parent]).all(axis=1))


# ---------------------------------------------------------------------------------------------
# export


def test_exported_vtu_reads_back_with_the_same_points_and_fields(bar, tmp_path):
    run_cli("export", bar, "--format", "vtu", "-o", tmp_path / "vtu", "--frames", "::2")
    with h5py.File(bar) as f:
        for i in (0, 2):
            mesh = meshio.read(tmp_path / "vtu" / f"bar_{i:04d}.vtu")
            np.testing.assert_array_equal(mesh.points, f["frames/points"][i])
            np.testing.assert_array_equal(mesh.cells_dict["tetra"], f["mesh/tets"][:])
            np.testing.assert_array_equal(mesh.point_data["displacement"], f["frames/points"][i] - f["mesh/points"][:])
            np.testing.assert_array_equal(mesh.point_data["velocities"], f["frames/velocities"][i])
            np.testing.assert_array_equal(mesh.point_data["speed"], f["frames/speed"][i])
            for name in ("von_mises", "pressure", "J"):
                np.testing.assert_array_equal(mesh.cell_data[name][0], f["frames"][name][i])
            np.testing.assert_array_equal(mesh.cell_data["stress"][0].reshape(-1, 3, 3), f["frames/stress"][i])
        pvd = (tmp_path / "vtu" / "bar.pvd").read_text()
        assert pvd.count("<DataSet") == 2 and f'timestep="{float(f["frames/time"][2])!r}"' in pvd
    assert sorted(p.name for p in (tmp_path / "vtu").iterdir()) == ["bar.pvd", "bar_0000.vtu", "bar_0002.vtu"]
    assert run_cli("export", bar, "--format", "vtu", "-o", tmp_path / "vtu", "--frames", "::2", ok=False).exit_code


def test_exported_xdmf_is_the_rest_mesh_with_displacement_and_its_h5_beside_it(bar, tmp_path, monkeypatch):
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")          # meshio alone would put the .h5 here
    target = tmp_path / "out" / "warp.xdmf"
    target.parent.mkdir()
    run_cli("export", bar, "--format", "xdmf", "-o", target)
    assert sorted(p.name for p in target.parent.iterdir()) == ["warp.h5", "warp.xdmf"]
    assert not list((tmp_path / "elsewhere").iterdir())
    with meshio.xdmf.TimeSeriesReader(str(target)) as reader, h5py.File(bar) as f:
        points, _ = reader.read_points_cells()
        np.testing.assert_array_equal(points, f["mesh/points"][:])
        assert reader.num_steps == f["frames/time"].shape[0]
        t, point_data, cell_data = reader.read_data(2)
        assert t == pytest.approx(f["frames/time"][2])
        np.testing.assert_array_equal(point_data["displacement"], f["frames/points"][2] - f["mesh/points"][:])
        np.testing.assert_array_equal(cell_data["von_mises"][0], f["frames/von_mises"][2])


def test_export_refuses_to_overwrite_the_run_file(bar, tmp_path):
    result = run_cli("export", bar, "--format", "xdmf", "-o", bar.with_suffix(".xdmf"), ok=False)
    assert result.exit_code != 0 and "would replace the run file" in result.output


def test_export_never_writes_its_data_over_another_run(bar, cube, tmp_path):
    """``-o cube.xdmf`` writes its arrays to ``cube.h5``: another run's results, kept even with
    --overwrite (only a file that is no run's is replaced)."""
    other = tmp_path / "cube.h5"
    other.write_bytes(cube.read_bytes())
    result = run_cli("export", bar, "--format", "xdmf", "-o", other.with_suffix(".xdmf"), "--overwrite", ok=False)
    assert result.exit_code != 0 and "holds another softsim run's results" in result.output
    assert other.read_bytes() == cube.read_bytes() and not other.with_suffix(".xdmf").exists()
    other.write_text("not a run\n")
    run_cli("export", bar, "--format", "xdmf", "-o", other.with_suffix(".xdmf"), "--overwrite")
    assert h5py.is_hdf5(other)


# ---------------------------------------------------------------------------------------------
# info and plot


def test_info_json_matches_the_file(bar):
    summary = json.loads(run_cli("info", bar, "--json").output)
    with h5py.File(bar) as f:
        assert summary["tets"] == f["mesh/tets"].shape[0] == 120
        assert summary["vertices"] == f["mesh/points"].shape[0]
        assert summary["frames"] == f["frames/time"].shape[0] == 3
        assert summary["time"] == pytest.approx(f["frames/time"][-1])
        assert summary["status"] == f.attrs["status"] == "complete"
        assert summary["steps"] == f.attrs["steps"] and summary["dt"] == f.attrs["dt"]
        assert summary["scene"]["model"] == "stvk"
        assert set(summary["fields"]) == {"velocities", "stress", "strain", "pressure", "von_mises", "J", "speed",
                                          "energy/kinetic", "energy/elastic", "energy/gravity"}
        for name, info in summary["fields"].items():
            data = f["frames"][name][:]
            assert info["min"] == data.min() and info["max"] == data.max(), name
        assert summary["fields"]["von_mises"]["unit"] == "Pa"
    text = run_cli("info", bar).output
    assert "120 tets" in text and "von_mises" in text and "complete" in text


def test_info_of_a_run_without_fields(cube):
    summary = json.loads(run_cli("info", cube, "--json").output)
    assert summary["fields"] == {}
    assert "none" in run_cli("info", cube).output


def test_plot_writes_a_png(bar, cube, tmp_path):
    import imageio.v3 as iio

    run_cli("plot", bar, "-o", tmp_path / "bar.png", "--vertex", "0", "--vertex", "62")
    run_cli("plot", cube, "-o", tmp_path / "cube.png")            # no energies: one panel
    for name in ("bar.png", "cube.png"):
        image = iio.imread(tmp_path / name)
        assert image.shape[0] > 200 and image[..., :3].std() > 10


# ---------------------------------------------------------------------------------------------
# bad input: one line, the key, what is allowed, non-zero exit


@pytest.mark.parametrize("args, expected", [
    (["info", "{scene}"], "not an HDF5 file"),
    (["render", "{bar}", "-o", "{tmp}/x.png", "--field", "stres"], "--field = 'stres': not available"),
    (["render", "{bar}", "-o", "{tmp}/x.png", "--frame", "3"], "frame 3: out of range"),
    (["render", "{bar}", "-o", "{tmp}/x.jpg"], ".png, .gif, .mp4"),
    (["render", "{cube}", "-o", "{tmp}/x.png", "--field", "von_mises"], "--field = 'von_mises': not available"),
    (["export", "{bar}", "--frames", "5:9"], "selects no frame"),
    (["export", "{bar}", "--frames", "x"], "expected N or start:stop[:step]"),
    (["export", "{bar}", "--frames", "-1", "-o", "{tmp}/one.txt"], "name a folder without an extension, or a .vtu"),
    (["export", "{bar}", "--frames", "0:2", "-o", "{tmp}/two.VTU"], "a single .vtu file holds one frame, but 2"),
    (["plot", "{bar}", "-o", "{tmp}/p.png", "--vertex", "1000"], "--vertex 1000: out of range"),
    (["info", "{tmp}/missing.h5"], "no such file"),
])
def test_bad_input_is_one_line_and_a_nonzero_exit(args, expected, bar, cube, tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text("mesh: {shape: box}\n")
    values = {"bar": bar, "cube": cube, "tmp": tmp_path, "scene": scene}
    result = run_cli(*[a.format(**values) for a in args], ok=False)
    assert result.exit_code != 0
    message = result.output.strip()
    assert expected in message and len(message.splitlines()) == 1 and "Traceback" not in message, message


def test_a_foreign_hdf5_file_is_refused(tmp_path):
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["data"] = np.zeros(3)
    with pytest.raises(ResultsError, match="not a softsim output file"):
        open_results(tmp_path / "other.h5")


def test_the_energy_sum_says_it_leaves_out_the_contact(bar):
    from softsim.viz.plot import total_energy_label

    with open_results(bar) as results:
        assert total_energy_label(results.scene) == "total"
        assert total_energy_label({**results.scene, "ground": {"height": 0.0}}) == "total (no contact energy)"


def test_missing_pyvista_or_matplotlib_names_the_extra(bar, tmp_path, monkeypatch):
    from softsim.viz.plot import plot_history
    from softsim.viz.render import render

    monkeypatch.setitem(__import__("sys").modules, "pyvista", None)
    with pytest.raises(MissingDependencyError, match=r'pip install "\.\[plot\]" in softsim'):
        render(bar, tmp_path / "x.png")
    monkeypatch.setitem(__import__("sys").modules, "matplotlib.figure", None)
    with pytest.raises(MissingDependencyError, match=r'pip install "\.\[plot\]" in softsim'):
        plot_history(bar, tmp_path / "x.png")
    result = run_cli("render", bar, "-o", tmp_path / "x.png", ok=False)
    assert result.exit_code != 0 and 'pip install ".[plot]"' in result.output


def test_frame_selection(bar):
    with open_results(bar) as results:
        assert results.select_frames(None) == [0, 1, 2]
        assert results.select_frames("::2") == [0, 2]
        assert results.select_frames("-1") == [2]
        assert results.select_frames("1:") == [1, 2]
        with pytest.raises(ResultsError, match="step must not be 0"):
            results.select_frames("::0")


def test_info_of_a_killed_run_shows_the_wall_time_of_its_last_frame(tmp_path):
    """The root ``wall_time_s`` is written when a run ends; a killed run's comes from its newest
    resume header."""
    import time

    from softsim.io.hdf5 import RunWriter
    from softsim.viz.info import summarize

    rng = np.random.default_rng(1)
    points, tets = rng.random((8, 3)), np.array([[0, 1, 2, 3], [4, 5, 6, 7]])
    writer = RunWriter(tmp_path / "killed.h5", points, tets, np.zeros(8, bool), "{}", 1e-3, 10, frames=10)
    writer.append_frame(0.0, 0, points, points)
    time.sleep(0.05)
    writer.append_frame(1e-3, 1, points, points)
    writer.file.close()                     # no finish: the file is left as a kill leaves it
    summary = summarize(tmp_path / "killed.h5")
    assert summary["status"] == "running" and summary["frames"] == 2
    assert summary["wall_time_s"] >= 0.05


def test_a_run_that_failed_before_its_first_frame_shows_its_status_and_reason(tmp_path):
    """``info`` shows a frameless file's status and reason; the commands that need frames name them."""
    from softsim.io.hdf5 import RunWriter

    rng = np.random.default_rng(2)
    points, tets = rng.random((4, 3)), np.array([[0, 1, 2, 3]])
    reason = "element 0 inverted (J = -1) at t = 0 s (step 0)"
    writer = RunWriter(tmp_path / "failed.h5", points, tets, np.zeros(4, bool), "{}", 1e-3, 10,
                       fields=("velocities", "energy"), frames=10)
    writer.finish("failed", reason)
    summary = json.loads(run_cli("info", tmp_path / "failed.h5", "--json").output)
    assert (summary["status"], summary["status_reason"], summary["frames"], summary["time"]) == (
        "failed", reason, 0, None)
    assert summary["fields"]["velocities"]["min"] is None and summary["fields"]["energy/kinetic"]["max"] is None
    text = run_cli("info", tmp_path / "failed.h5").output
    assert f"status   failed ({reason})" in text and "frames   none" in text
    for args in (["plot", "-o", tmp_path / "p.png"], ["export", "--format", "vtu", "-o", tmp_path / "vtu"],
                 ["render", "-o", tmp_path / "r.png"]):
        result = run_cli(args[0], tmp_path / "failed.h5", *args[1:], ok=False)
        assert result.exit_code == 1
        assert result.output.strip() == f"Error: '{tmp_path / 'failed.h5'}': holds no frames (status: failed, {reason})"
