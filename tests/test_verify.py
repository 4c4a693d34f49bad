"""``softsim verify``: the quick report as a real check, and mutation tests proving that each
threshold catches a broken kernel.

The quick report runs once (module fixture).  Every threshold is stated next to why it holds,
from the scene's own parameters; the mutation tests feed a broken quantity into the prepared
model (``mutate``: mu doubled, lambda and mu swapped, rest volumes scaled, Dm^-1 transposed) and
check that the same threshold then fails.  nu is far from 0.25 wherever a swap must show
(lambda = mu there).
"""

import csv
import math
from dataclasses import replace

import numpy as np
import pytest

from softsim.integrators import symplectic_euler
from softsim.kernels.compile_ahead import argument_types
from softsim.verify import references as ref
from softsim.verify.cases import CASES, AxialVibration, Cantilever, Energy, Traction
from softsim.verify.driver import with_lame, with_rest_state
from softsim.errors import ConfigError
from softsim.verify.report import COLUMNS, ladders, pareto_front, verify_report

ROTATION_INVARIANT = ("stvk", "corotated", "neohookean")


# The specialisations of the compiled step that the quick report's runs called, (kernel, argument types).
QUICK_REPORT_STEPS = set()


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("verify")
    with pytest.MonkeyPatch.context() as patch:
        make_call = symplectic_euler.advance_driver

        def recording_driver(*arguments):
            kernel, kernel_arguments = make_call(*arguments)
            QUICK_REPORT_STEPS.add((kernel, argument_types(kernel, kernel_arguments)))
            return kernel, kernel_arguments

        patch.setattr(symplectic_euler, "advance_driver", recording_driver)
        return verify_report(out, quick=True, threads=1, precisions=("float64",))


def rows_of(rows, case, quantity, model=None, ladder=None):
    return [r for r in rows if r.case == case and r.quantity == quantity and (model is None or r.model == model)
            and (ladder is None or r.ladder == ladder)]


# ---------------------------------------------------------------------------------------------
# Thresholds (each a function of the rows of one case, so the mutation tests reuse them)


def cantilever_failures(rows):
    """Linear tets lock: each model's deflection must grow under refinement and stay below the 3D
    answer (<= 1.03 x Timoshenko), and the Richardson limit of the ladder must land within
    0.97-1.10 x Timoshenko (measured: 0.995 from t/4, t/6, t/8; 1.05 from the quick ladder t/2, t/3,
    t/4, which extrapolates from the pre-asymptotic range with order 1.2).  Stiffness 25 % off
    moves the limit out of that band (volumes x 0.8: 1.32; mu x 2: 0.56; swap at nu = 0.3: 0.76)."""
    p = CASES["cantilever"].params
    _, w_t = ref.cantilever_tip_deflection(p.length, p.thickness, p.thickness, p.youngs_modulus,
                                           p.poissons_ratio, p.density, p.gravity)
    failures = []
    for model in {r.model for r in rows}:
        ladder = sorted(rows_of(rows, "cantilever", "tip deflection", model), key=lambda r: -r.refinement)
        w = [r.value for r in ladder]
        if len(w) < 3:
            continue      # the check needs three rungs
        if any(b <= a for a, b in zip(w, w[1:])) or max(w) > 1.03 * w_t:
            failures.append(f"{model}: deflections {w} not increasing below 1.03 x {w_t:.4g}")
        limit, _, _ = ref.richardson_limit([r.refinement for r in ladder], w)
        if not 0.97 < limit / w_t < 1.10:
            failures.append(f"{model}: Richardson limit / Timoshenko = {limit / w_t:.4f}")
        if any("NOT at rest" in r.note for r in ladder):
            failures.append(f"{model}: not at rest")
    return failures


def axial_failures(rows, p=AxialVibration()):
    """Period error at most 1.5 x the 1D lumped-mass dispersion (k h)^2 / 24 with k = pi / 2L (the
    measured error is 1.1 x it; symplectic Euler's shortening only reduces it)."""
    failures = []
    k = 0.5 * math.pi / p.length
    for r in rows_of(rows, "axial-vibration", "period"):
        h = r.element_size
        if not r.error < 1.5 * (k * h) ** 2 / 24.0:
            failures.append(f"{r.model} h={h:g} dt={r.dt:.3g}: period error {r.error:.3g}")
    return failures


def traction_failures(rows):
    """linear and corotated: the homogeneous stretch is exact, error below 1e-7 (relaxation to
    1e-9); stvk and neohookean: within 2 sigma/E of small-strain theory (finite strain); every
    model within 1e-7 of its own law's exact homogeneous stretch."""
    failures = []
    for quantity in ("elongation, exact stretch", "contraction, exact stretch"):
        for r in rows_of(rows, "traction", quantity):
            if not r.error < 1e-7:
                failures.append(f"{r.model} {quantity}: error {r.error:.3g}")
    for r in rows_of(rows, "traction", "elongation") + rows_of(rows, "traction", "contraction"):
        load = float(r.note.split("sigma/E = ")[1].split(";")[0])
        bound = 1e-7 if r.model in ("linear", "corotated") else 2.0 * load
        if not r.error < bound or "NOT at rest" in r.note:
            failures.append(f"{r.model} {r.quantity} sigma/E={load:g}: error {r.error:.3g} >= {bound:g}")
    return failures


def patch_failures(rows):
    """Interior forces at x = A X + b below 1e-11 of the boundary reactions; after relaxation
    max |F - A| below 1e-9 of |A - I| (round-off is ~1e-13 and ~1e-11)."""
    failures = []
    for r in rows_of(rows, "patch", "interior force at AX+b"):
        if not r.error < 1e-11:
            failures.append(f"{r.model}: interior force residual {r.error:.3g}")
    for r in rows_of(rows, "patch", "max |F - A|"):
        if not r.error < 1e-9:
            failures.append(f"{r.model}: max |F - A| = {r.error:.3g}")
    return failures


def energy_failures(rows, p=Energy()):
    """Energy error below 2e-3 x dt / dt_auto (measured 1.6e-3 at dt: auto, first order in dt); the
    trend over the run below a tenth of the oscillation (bounded, no drift)."""
    failures = []
    for r in rows_of(rows, "energy", "energy error"):
        bound = 2e-3 * r.dt / max(x.dt for x in rows_of(rows, "energy", "energy error", r.model))
        if not r.error < bound:
            failures.append(f"{r.model} dt={r.dt:.3g}: energy error {r.error:.3g}")
    for r in rows_of(rows, "energy", "energy drift"):
        error = rows_of(rows, "energy", "energy error", r.model)
        oscillation = next(x.error for x in error if x.dt == r.dt)
        if not r.error < 0.1 * oscillation:
            failures.append(f"{r.model} dt={r.dt:.3g}: drift {r.error:.3g} vs oscillation {oscillation:.3g}")
    return failures


# ---------------------------------------------------------------------------------------------
# The quick report


def test_quick_report_writes_csv_plots_and_summary(report):
    assert report.csv_path.is_file()
    with open(report.csv_path) as stream:
        table = list(csv.reader(stream))
    assert tuple(table[0]) == COLUMNS
    assert len(table) == len(report.rows) + 1
    assert set(report.plot_paths) == set(CASES)
    for path in report.plot_paths.values():
        assert path.is_file() and path.stat().st_size > 10_000
    text = report.summary_path.read_text()
    for name in CASES:
        assert f"verify_{name}.png" in text
    assert "1 %:" in text and "0.1 %:" in text
    assert {r.model for r in report.rows} == {"linear", "stvk", "corotated", "neohookean"}
    assert all(r.precision == "float64" and r.wall_time_s > 0.0 for r in report.rows)
    assert all(r.steps > 0 for r in report.rows if r.quantity != "interior force at AX+b")


def test_float32_rows_match_float64_to_float32_round_off():
    """``precisions`` adds float32 rows for the models that have a float32 step: the cantilever's
    deflections agree with float64 to 1e-5 (float32 keeps 7 digits; the tip sags 1e-3 m), and the
    report's ladders keep the two precisions apart."""
    rows = CASES["cantilever"](models=("stvk", "corotated"), quick=True, precisions=("float64", "float32"))
    assert {(r.model, r.precision) for r in rows} == {("stvk", "float64"), ("stvk", "float32"),
                                                       ("corotated", "float64")}
    pairs = {}
    for r in rows:
        if r.quantity == "tip deflection" and r.model == "stvk":
            pairs.setdefault(r.tets, {})[r.precision] = r.value
    assert len(pairs) == 3
    for values in pairs.values():
        assert abs(values["float32"] - values["float64"]) < 1e-5 * abs(values["float64"])
    keys = {key for key in ladders(rows) if key[1] == "tip deflection"}
    assert ("cantilever", "tip deflection", "stvk float32", "element_size") in keys
    assert all(len(group) == 3 for key, group in ladders(rows).items() if key[1] == "tip deflection")


def test_quick_cantilever_converges_towards_the_3d_beam(report):
    for model in ("linear", "stvk", "neohookean"):
        assert len(rows_of(report.rows, "cantilever", "tip deflection", model)) >= 3
    assert cantilever_failures(report.rows) == []


def test_quick_axial_period_is_second_order_in_h(report):
    assert axial_failures(report.rows) == []
    for model in ("linear", "stvk", "corotated", "neohookean"):
        ladder = rows_of(report.rows, "axial-vibration", "period", model, "element_size")
        orders = [r.order for r in ladder if r.order is not None]
        assert orders and all(1.8 < o < 2.2 for o in orders), orders


def test_quick_traction_is_exact_for_a_homogeneous_stretch(report):
    assert traction_failures(report.rows) == []
    for model in ("stvk", "neohookean"):       # finite strain: first order in the load
        ladder = rows_of(report.rows, "traction", "elongation", model, "load")
        assert all(0.9 < r.order < 1.1 for r in ladder if r.order is not None)


def test_quick_free_fall_error_is_exactly_dt_over_t(report):
    for r in rows_of(report.rows, "rigid-motion", "centroid drop"):
        expected = r.dt / (r.steps * r.dt)          # symplectic Euler leads g t^2 / 2 by g t dt / 2
        assert r.error == pytest.approx(expected, rel=1e-6)


def test_quick_spin_keeps_shape_and_angular_momentum_except_linear(report):
    p = CASES["rigid-motion"].params
    radius = 0.5 * math.sqrt(3.0) * p.size
    omega = math.sqrt(p.spin_strain * p.youngs_modulus / (p.density * radius ** 2))
    for r in rows_of(report.rows, "rigid-motion", "edge length"):
        if r.model in ROTATION_INVARIANT:
            assert r.error < 2.0 * p.spin_strain
        else:
            growth = math.sqrt(1.0 + (omega * r.steps * r.dt) ** 2) - 1.0
            assert r.error == pytest.approx(growth, rel=1e-2)
    for r in rows_of(report.rows, "rigid-motion", "angular momentum"):
        assert r.error < 1e-10


def test_quick_patch_test_holds_to_round_off(report):
    assert patch_failures(report.rows) == []


def test_quick_energy_stays_bounded_and_its_error_is_first_order_in_dt(report):
    assert energy_failures(report.rows) == []
    for r in rows_of(report.rows, "energy", "energy error"):
        if r.order is not None:
            assert 0.9 < r.order < 1.1


def test_the_steps_recorded_ahead_are_those_the_quick_report_runs(report):
    # ``softsim verify`` compiles the steps its cases will run before the first timed step, from
    # each case's first run of each model (``Case.step_calls``); a later run compiling a step of
    # its own would compile alone, and one recorded but never run would be compiled for nothing.
    recorded = {(kernel, argument_types(kernel, arguments))
                for case in CASES.values() for kernel, arguments in case.step_calls(quick=True)}
    assert len(QUICK_REPORT_STEPS) >= 3            # no damping, damping, damping and tractions
    assert recorded == QUICK_REPORT_STEPS


def test_budget_answers_name_a_run_or_say_why_not(report):
    for name, lines in report.budgets.items():
        assert len(lines) == 2, name
        for line in lines:
            assert "element size" in line or "not reached" in line or "cannot be told" in line


def test_pareto_front_keeps_only_undominated_points():
    times = [1.0, 2.0, 3.0, 0.5, 2.5]
    errors = [0.1, 0.05, 0.2, 0.3, 0.01]
    assert pareto_front(times, errors) == [3, 0, 1, 4]


def test_richardson_limit_recovers_a_second_order_sequence():
    h = [0.4, 0.2, 0.1]
    limit, k, spread = ref.richardson_limit(h, [3.0 + 0.5 * x ** 2 for x in h])
    assert limit == pytest.approx(3.0, abs=1e-12) and k == pytest.approx(2.0, abs=1e-6) and spread < 1e-12


# ---------------------------------------------------------------------------------------------
# Mutation tests: the thresholds above catch broken kernels


def mu_doubled(model):
    return with_lame(model, mu=2.0 * model.mu)


def lame_swapped(model):
    return with_lame(model, lam=model.mu, mu=model.lam)


def volumes_scaled(model):
    return with_rest_state(model, rest_volume=0.8 * model.rest_volume)


MUTATIONS = {"mu doubled": mu_doubled, "lambda and mu swapped": lame_swapped, "rest volumes x 0.8": volumes_scaled}


@pytest.mark.parametrize("model", ["linear", "neohookean"])
@pytest.mark.parametrize("mutation", MUTATIONS)
def test_traction_threshold_catches(mutation, model):
    """nu = 0.4 (lambda = 4 mu): each mutation changes the elongation or the contraction."""
    rows = CASES["traction"](models=(model,), mutate=MUTATIONS[mutation], quick=True,
                             params=replace(Traction(), quick_load_ratios=(1e-3,), quick_element_sizes=()))
    assert traction_failures(rows) != []


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_axial_threshold_catches(mutation):
    """nu = 0, lambda = 0: a swap leaves mu = 0 and the bar's stiffness lambda' = E / 2."""
    rows = CASES["axial-vibration"](models=("stvk",), mutate=MUTATIONS[mutation], quick=True,
                                    params=replace(AxialVibration(), quick_divisions=(10,), quick_dt_factors=()))
    assert axial_failures(rows) != []


def tets_perturbed(model):
    rng = np.random.default_rng(1)
    return with_rest_state(model, rest_volume=model.rest_volume * rng.uniform(0.9, 1.1, model.tet_count))


def dm_inv_transposed(model):
    return with_rest_state(model, Dm_inv=np.transpose(model.Dm_inv, (0, 2, 1)))


@pytest.mark.parametrize("mutation", [tets_perturbed, dm_inv_transposed])
def test_patch_threshold_catches(mutation):
    """Uniform F is an equilibrium only if each tet's force is consistent with its geometry."""
    rows = CASES["patch"](models=("corotated",), mutate=mutation, quick=True)
    assert patch_failures(rows) != []


def test_energy_threshold_catches_a_force_inconsistent_with_the_energy():
    """Energies are measured with the model as built; a stepped model with mu doubled has forces
    that are not the gradient of that energy."""
    rows = CASES["energy"](models=("neohookean",), mutate=mu_doubled, quick=True,
                           params=replace(Energy(), quick_dt_factors=(1.0,), quick_periods=3.0))
    assert energy_failures(rows) != []


@pytest.mark.parametrize("mutation", MUTATIONS)
@pytest.mark.slow                       # runs with SOFTSIM_SLOW=1 (conftest)
def test_cantilever_threshold_catches(mutation):
    """nu = 0.3 is far enough from 0.25 here: the swap makes the beam 38 % stiffer in bending."""
    rows = CASES["cantilever"](models=("stvk",), mutate=MUTATIONS[mutation], quick=True,
                               params=replace(Cantilever(), rest_tolerance=1e-5))
    assert cantilever_failures(rows) != []


# ---------------------------------------------------------------------------------------------
# Front door


def test_cli_verify_runs_a_case_and_prints_the_table(tmp_path):
    from click.testing import CliRunner

    from softsim.cli.main import cli

    out = tmp_path / "report"
    result = CliRunner().invoke(cli, ["verify", "--quick", "--case", "traction", "--model", "linear", "--threads", "1",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert "traction" in result.output and "elongation" in result.output and "1 %:" in result.output
    assert (out / "verify.csv").is_file() and (out / "verify.md").is_file() and (out / "verify_traction.png").is_file()


def test_cli_verify_refuses_an_unknown_case_in_one_line(tmp_path):
    from click.testing import CliRunner

    from softsim.cli.main import cli

    result = CliRunner().invoke(cli, ["verify", "--case", "nonsense", "-o", str(tmp_path)])
    assert result.exit_code != 0 and "nonsense" in result.output


def test_without_matplotlib_the_tables_are_written_and_the_extra_named(tmp_path, monkeypatch):
    from softsim.errors import MissingDependencyError
    from softsim.verify import report as report_module

    def missing():
        raise MissingDependencyError("no matplotlib")

    monkeypatch.setattr(report_module, "_matplotlib", missing)
    result = verify_report(tmp_path, quick=True, cases=["rigid-motion"], models=["stvk"], threads=1)
    assert result.plot_paths == {} and 'pip install ".[plot]"' in result.plot_note
    assert result.csv_path.is_file() and 'pip install ".[plot]"' in result.summary_path.read_text()


def test_a_report_re_renders_from_its_table(report, tmp_path):
    from softsim.verify.report import read_csv, write_report

    rows = read_csv(report.csv_path)
    assert len(rows) == len(report.rows)
    again = write_report(tmp_path, rows, quick=True, plot=False)
    assert again.csv_path.read_text() == report.csv_path.read_text()
    # the table keeps wall times to 6 digits: the same cheapest runs, unless a time sits on TIME_NOISE's edge
    assert again.budgets == report.budgets


def test_cli_replot_redraws_from_the_table_without_running(report, tmp_path):
    import shutil

    from click.testing import CliRunner

    from softsim.cli.main import cli

    copy = tmp_path / "copy"
    shutil.copytree(report.out_dir, copy)
    for png in copy.glob("*.png"):
        png.unlink()
    result = CliRunner().invoke(cli, ["verify", "--replot", "-o", str(copy)])
    assert result.exit_code == 0, result.output
    assert len(list(copy.glob("verify_*.png"))) == len(CASES)
    assert (copy / "verify.csv").read_text() == report.csv_path.read_text()
    assert "Quick run" in (copy / "verify.md").read_text()
    assert f"(redrawn; the runs took {report.wall_time_s:.0f} s)" in result.output    # not as its own time
    missing = CliRunner().invoke(cli, ["verify", "--replot", "-o", str(tmp_path / "nothing")])
    assert missing.exit_code != 0 and "verify.csv" in missing.output


def test_a_report_that_cannot_be_written_or_has_nothing_to_run_is_refused_before_any_run(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match=r"^-o = '.*file/out': cannot write there \("):
        verify_report(blocker / "out", quick=True, cases=["patch"])
    with pytest.raises(ConfigError, match=r"^--precision float32: corotated steps in float64 only"):
        verify_report(tmp_path / "v", quick=True, cases=["patch"], models=["corotated"], precisions=["float32"])
    assert not (tmp_path / "v").exists()


def test_replot_of_a_table_that_is_not_verifys_is_one_line(tmp_path):
    from softsim.verify.report import replot_report

    (tmp_path / "verify.csv").write_text("case,quantity\npatch,x\n")
    with pytest.raises(ConfigError, match=r"verify.csv': not a table softsim verify wrote \(no column model, "):
        replot_report(tmp_path)
    (tmp_path / "verify.csv").write_text(",".join(COLUMNS) + "\n" + ",".join(["x"] * len(COLUMNS)) + "\n")
    with pytest.raises(ConfigError, match=r"verify.csv' line 2: could not convert string to float: 'x'"):
        replot_report(tmp_path)


def test_the_cheapest_run_for_a_budget_does_not_follow_timer_noise():
    """Runs within TIME_NOISE of the fastest are equals: the least work among them is the answer."""
    from softsim.verify.cases import VerifyRow
    from softsim.verify.report import TIME_NOISE, budget_answers

    def row(tets, steps, wall, error):
        return VerifyRow(case="axial-vibration", quantity="period", model="stvk", precision="float64",
                         ladder="element_size", refinement=1.0, element_size=0.1, tets=tets, dt=1e-4, steps=steps,
                         wall_time_s=wall, value=1.0, reference_value=1.0, error=error, reference="theory",
                         order=None, order_self=None, note="", reference_uncertainty=0.0)

    less_work = row(400, 604, 0.030, 2.7e-4)             # timed slowly once
    more_work = row(800, 1204, 0.0207, 3.1e-4)
    too_slow = row(100, 100, 0.0207 * (1 + TIME_NOISE) * 1.01, 5e-4)
    lines = budget_answers([more_work, less_work, too_slow], "axial-vibration", "period", budgets=(1e-3,))
    assert len(lines) == 1 and "604 steps" in lines[0], lines
    lines = budget_answers([more_work, row(400, 604, 0.0207 * 3, 2.7e-4)], "axial-vibration", "period",
                           budgets=(1e-3,))
    assert "1204 steps" in lines[0], lines                # three times as slow is no noise


def test_a_re_rendered_report_names_the_same_times_where_the_table_rounds_across_a_digit(tmp_path):
    """The table keeps 6 digits of a wall time and a budget's answer 3: 0.12549999996 s reads
    0.125 s, but 0.1255 s (as the table has it) reads 0.126 s.  The answers come from the
    table's values, so the report and its re-render say the same."""
    from softsim.verify.cases import VerifyRow
    from softsim.verify.report import read_csv, write_report

    row = VerifyRow(case="axial-vibration", quantity="period", model="stvk", precision="float64",
                    ladder="element_size", refinement=0.1, element_size=0.1, tets=400, dt=1e-4, steps=604,
                    wall_time_s=0.12549999996, value=1.0, reference_value=1.0, error=2.7e-4, reference="theory")
    first = write_report(tmp_path / "a", [row], quick=True, plot=False)
    again = write_report(tmp_path / "b", read_csv(first.csv_path), quick=True, plot=False)
    assert "0.126 s" in first.budgets["axial-vibration"][0]
    assert again.budgets == first.budgets


def test_replot_refuses_the_options_of_a_run(tmp_path):
    from click.testing import CliRunner

    from softsim.cli.main import cli

    result = CliRunner().invoke(cli, ["verify", "--replot", "--case", "patch", "--threads", "1", "-o", str(tmp_path)])
    assert result.exit_code == 2
    assert "--replot runs nothing, so --case, --threads would not apply" in result.output
