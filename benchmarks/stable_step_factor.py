"""How far is symplectic Euler's true stability limit from the ``dt: auto`` estimate?

For every material model and a range of meshes (structured boxes of several element sizes and cell
aspect ratios, gmsh boxes, a gmsh sphere and cylinder, structured boxes with randomly perturbed
nodes, which have slivers), Poisson ratios and Young's moduli, this measures

    ratio = exact_stable_step / altitude estimate

where ``exact_stable_step = 2 / sqrt(lambda_max(M^-1 K))`` (``softsim.integrators.stability``,
Lanczos on the tangent stiffness at rest) and the altitude estimate is ``h_min / c_p``, what
``altitude_step_estimate`` below gives (softsim used it before the nodal bound).  ``dt: auto`` ran
at ``AUTO_SAFETY x`` the estimate, so it is safe where ``AUTO_SAFETY <= ratio`` and not wasteful
(true limit at most 2x the step in use) where ``ratio <= 2 AUTO_SAFETY``.

It also reports, for comparison, the rigorous nodal bound ``stability.nodal_frequency_bound``
(``dt_nodal = 2 / sqrt(bound)``, never above the true limit at rest): ``exact / dt_nodal >= 1``.

A second table re-checks the ratios on deformed states (uniaxial compression and stretch, shear),
where the tangent depends on the model and the estimate uses the deformed mesh's altitudes (the
per-frame re-check of the issue); a third adds a stiff penalty ground; a fourth times the exact
computation at about 10k and 100k tets.

    python benchmarks/stable_step_factor.py            # everything (a few minutes)
    python benchmarks/stable_step_factor.py --quick    # fewer meshes and moduli
"""

import argparse
import dataclasses
import math
import statistics
import time
from collections import defaultdict

import numba
import numpy as np

from softsim.config import parse_scene
from softsim.integrators.stability import exact_stable_step, frequency_analysis, nodal_frequency_bound
from softsim.integrators.timestep import AUTO_SAFETY, dilatational_wave_speed
from softsim.kernels.blocked import build_block_layout, uses_triangular_rest
from softsim.kernels.forces import elastic_forces
from softsim.materials.models import MODEL_IDS, model_lame_parameters
from softsim.mesh import checked_mesh
from softsim.mesh.generate import gmsh_box, gmsh_cylinder, gmsh_sphere, structured_box
from softsim.mesh.quality import altitudes, dihedral_angles
from softsim.model import build_model

MODELS = ("linear", "stvk", "corotated", "neohookean")
POISSON = (0.3, 0.45, 0.49, 0.499)
YOUNG = (1e5, 1e7, 1e9, 2e11)
DENSITY = {1e5: 1000.0, 1e6: 1000.0, 1e7: 1100.0, 1e9: 1500.0, 2e11: 7850.0}   # rubber ... steel [kg/m^3]


# ---------------------------------------------------------------------------------------------
# meshes



def altitude_step_estimate(min_altitude, wave_speed, contact_stiffness=None, mass=None):
    """The older stable-step estimate [s]: ``h_min / c_p``, combined with the ground's penalty
    frequency as ``1/dt^2 = 1/dt_el^2 + (omega_max / 2)^2`` (kept here to measure it against)."""
    inverse_square = (wave_speed / min_altitude) ** 2
    if contact_stiffness is not None:
        inverse_square += np.max(contact_stiffness / mass, initial=0.0) / 4.0
    return 1.0 / math.sqrt(inverse_square)

def perturbed_box(size, element_size, amount, seed=1):
    """Structured box whose interior nodes move by up to ``amount x`` the cell size per axis (slivers)."""
    points, tets = structured_box(size, (0.0, 0.0, 0.0), element_size)
    rng = np.random.default_rng(seed)
    interior = np.all((points > 1e-9) & (points < np.asarray(size) - 1e-9), axis=1)
    for _ in range(50):           # shrink the perturbation until no tet inverts
        moved = points.copy()
        moved[interior] += amount * element_size * rng.uniform(-1.0, 1.0, (interior.sum(), 3))
        X = moved[tets]
        if (np.linalg.det(X[:, 1:] - X[:, :1]) > 0).all():
            return moved, tets
        amount *= 0.9
    raise RuntimeError("could not perturb the box without inverting a tet")


def graded_box(size, element_size, thin_fraction):
    """Structured box whose middle layer of cells along z is ``thin_fraction`` of the others (flat tets)."""
    nz = max(3, int(round(size[2] / element_size)))
    widths = np.ones(nz)
    widths[nz // 2] = thin_fraction
    z = np.concatenate([[0.0], np.cumsum(widths)]) / widths.sum() * size[2]
    points, tets = structured_box((size[0], size[1], float(nz)), (0.0, 0.0, 0.0), (element_size, element_size, 1.0))
    points[:, 2] = np.interp(points[:, 2], np.arange(nz + 1), z)
    return points, tets


def mesh_catalogue(quick):
    """List of ``(kind, name, points, tets)``."""
    out = []

    def add(kind, name, points_tets):
        points, tets = points_tets
        out.append((kind, name, points, tets))

    cube = (1.0, 1.0, 1.0)
    beam = (1.0, 0.1, 0.1)
    for h in ((0.5, 0.25, 0.125) if quick else (0.5, 0.25, 0.125, 0.0625)):
        add("structured", f"cube h={h}", structured_box(cube, (0, 0, 0), h))
    for h in ((0.05, 0.025) if quick else (0.05, 0.025, 0.0125)):
        add("structured", f"beam 1x0.1x0.1 h={h}", structured_box(beam, (0, 0, 0), h))
    add("structured-aniso", "plate cells 0.2x0.2x0.1", structured_box((1.0, 1.0, 0.1), (0, 0, 0), 0.2))
    add("structured-aniso", "beam cells 0.05x0.025x0.025", structured_box((1.0, 0.1, 0.1), (0, 0, 0),
                                                                          (0.05, 0.025, 0.025)))
    if not quick:
        add("structured-aniso", "cube, one layer 1/10 thick", graded_box(cube, 0.2, 0.1))
    for h in ((0.25, 0.125) if quick else (0.25, 0.125, 0.0625)):
        add("gmsh-box", f"cube h={h}", gmsh_box(cube, (0, 0, 0), h))
    for h in ((0.05,) if quick else (0.05, 0.025)):
        add("gmsh-box", f"beam 1x0.1x0.1 h={h}", gmsh_box(beam, (0, 0, 0), h))
    for h in ((0.2,) if quick else (0.2, 0.1, 0.05)):
        add("gmsh-sphere", f"r=0.5 h={h}", gmsh_sphere(0.5, (0, 0, 0), h))
    for h in ((0.05,) if quick else (0.05, 0.025)):
        add("gmsh-cylinder", f"r=0.1 L=1 h={h}", gmsh_cylinder(0.1, 1.0, "x", (0, 0, 0), h))
    for amount in ((0.3,) if quick else (0.15, 0.3, 0.4)):
        add("perturbed", f"cube h=0.125 +-{amount}h", perturbed_box(cube, 0.125, amount))
    return out


# ---------------------------------------------------------------------------------------------
# one measurement


def scene_for(model, E, nu, fixed=None, ground=None):
    """A validated scene (its mesh section is a placeholder: the mesh is passed to build_model)."""
    data = {"mesh": {"shape": "box", "size": [1, 1, 1], "element_size": 1.0},
            "material": {"model": model, "youngs_modulus": E, "poissons_ratio": nu, "density": DENSITY[E]},
            "gravity": [0.0, 0.0, 0.0]}
    if fixed is not None:
        data["fixed"] = fixed
    if ground is not None:
        data["ground"] = ground
    return parse_scene(data)


def altitude_estimate(scene, model, x=None):
    """The ``dt: auto`` estimate before the safety factor [s] (as ``simulation.stable_dt_estimate``)."""
    m = scene.material
    c_p = dilatational_wave_speed(m.youngs_modulus, m.poissons_ratio, m.density)
    h_min = float(altitudes(model.rest_points if x is None else x, model.tets).min())
    if model.has_ground:
        return altitude_step_estimate(h_min, c_p, model.contact_stiffness_bound, model.mass)
    return altitude_step_estimate(h_min, c_p)


_model_cache = {}


def model_for(scene, mesh):
    """``build_model(scene, mesh)``, reusing the mesh-dependent arrays of the last scene on ``mesh``.

    Only the material fields depend on the scene here (every scene differs in its material alone
    unless it has fixed boxes or a ground, which are built in full); the first reuse is checked
    against a full build.
    """
    if scene.fixed or scene.ground is not None:
        return build_model(scene, mesh)
    base = _model_cache.get(id(mesh))
    if base is None or base[0] is not mesh:
        model = build_model(scene, mesh)
        _model_cache.clear()
        _model_cache[id(mesh)] = (mesh, model, False)
        return model
    _, model0, checked = base
    m = scene.material
    lam, mu = model_lame_parameters(m.model, m.youngs_modulus, m.poissons_ratio)
    rho0 = model0.mass.sum() / model0.rest_volume.sum()
    mass = model0.mass * (m.density / rho0)
    inv_mass = np.where(mass > 0.0, 1.0 / np.where(mass > 0.0, mass, 1.0), 0.0)
    model = dataclasses.replace(model0, material_id=MODEL_IDS[m.model], lam=float(lam), mu=float(mu),
                                mass=mass, inv_mass=inv_mass)
    if uses_triangular_rest(model.material_id, model0.blocks.rest.dtype) != model0.blocks.triangular:
        model = dataclasses.replace(model, blocks=build_block_layout(      # the rest data's form follows the law
            model.tets, model.Dm_inv, model.rest_volume, model.node_count, dtype=model0.blocks.rest.dtype,
            model=model.material_id))
    if not checked:
        full = build_model(scene, mesh)
        for field in ("material_id", "lam", "mu", "mass", "inv_mass"):
            assert np.allclose(getattr(full, field), getattr(model, field), rtol=1e-12, atol=0.0), field
        _model_cache[id(mesh)] = (mesh, model0, True)
    return model


def measure(scene, mesh, x=None, with_bound=True):
    """``(exact, estimate, nodal bound step)`` [s] for ``scene`` on ``mesh`` at positions ``x`` (rest)."""
    model = model_for(scene, mesh)
    if x is not None:
        x = model.from_user_order(x)
    exact = exact_stable_step(model, x)
    estimate = altitude_estimate(scene, model, x)
    bound = 2.0 / np.sqrt(nodal_frequency_bound(model, x)) if with_bound else float("nan")
    return exact, estimate, bound


def summary_line(label, values):
    return (f"{label:<34} n={len(values):>4}  min {min(values):6.3f}  median {statistics.median(values):6.3f}"
            f"  max {max(values):6.3f}")


# ---------------------------------------------------------------------------------------------
# tables


def rest_table(meshes, young):
    print("\n== At rest, free bodies: ratio = exact / altitude estimate;  nodal = exact / nodal-bound step ==")
    print(f"{'kind':<17} {'mesh':<30} {'tets':>6} {'min dih':>7} {'nu':>6} "
          + " ".join(f"{m:>10}" for m in MODELS) + f" {'E spread':>9} {'nodal':>7}")
    by_kind_model = defaultdict(list)
    by_kind_nodal = defaultdict(list)
    by_kind_nu = defaultdict(list)
    for kind, name, points, tets in meshes:
        mesh = checked_mesh(points, tets, name)
        min_dihedral = float(dihedral_angles(mesh.points, mesh.tets).min())
        for nu in POISSON:
            ratios = {}
            spread = []
            nodal = None
            for model_name in MODELS:
                per_E = []
                for E in young:
                    exact, estimate, bound = measure(scene_for(model_name, E, nu), mesh,
                                                     with_bound=(nodal is None))
                    per_E.append(exact / estimate)
                    if nodal is None:
                        nodal = exact / bound
                    by_kind_model[(kind, model_name)].append(exact / estimate)
                    by_kind_nu[(kind, nu)].append(exact / estimate)
                ratios[model_name] = per_E[0]
                spread.append(max(per_E) / min(per_E) - 1.0)
            by_kind_nodal[kind].append(nodal)
            print(f"{kind:<17} {name:<30} {mesh.tet_count:>6} {min_dihedral:7.1f} {nu:6.3f} "
                  + " ".join(f"{ratios[m]:10.4f}" for m in MODELS) + f" {max(spread):9.1e} {nodal:7.3f}",
                  flush=True)
    print("\n-- exact / altitude estimate, per mesh kind and model (all nu, all E) --")
    for key in sorted(by_kind_model):
        print(summary_line(f"{key[0]} / {key[1]}", by_kind_model[key]))
    print("\n-- exact / altitude estimate, per mesh kind and nu (all models, all E) --")
    for key in sorted(by_kind_nu):
        print(summary_line(f"{key[0]} / nu={key[1]}", by_kind_nu[key]))
    print("\n-- exact / nodal-bound step, per mesh kind (all nu; >= 1 by construction) --")
    for key in sorted(by_kind_nodal):
        print(summary_line(key, by_kind_nodal[key]))
    everything = [r for values in by_kind_model.values() for r in values]
    nodal_all = [r for values in by_kind_nodal.values() for r in values]
    return everything, nodal_all, by_kind_model


def steel_beam_table():
    print("\n== Steel cantilever 1 x 0.1 x 0.1 m, E = 200 GPa, nu = 0.3, rho = 7850, held at x = 0 ==")
    fixed = [{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}]
    rows = []
    for kind, builder in (("structured", structured_box), ("gmsh-box", gmsh_box)):
        for h in (0.05, 0.025, 0.02):
            points, tets = builder((1.0, 0.1, 0.1), (0, 0, 0), h)
            mesh = checked_mesh(points, tets, kind)
            scene = scene_for("stvk", 2e11, 0.3, fixed=fixed)
            exact, estimate, bound = measure(scene, mesh)
            rows.append(exact / estimate)
            print(f"{kind:<12} h={h:<6} {mesh.tet_count:>6} tets: exact {exact:.4e} s, estimate {estimate:.4e} s, "
                  f"ratio {exact / estimate:.3f}; nodal-bound step {bound:.4e} s (exact / it {exact / bound:.3f})")
    return rows


def deformed_table(quick):
    print("\n== Deformed states (estimate from the deformed mesh's altitudes, rest wave speed) ==")
    deformations = {
        "compress z 0.5": np.diag([1.0, 1.0, 0.5]),
        "compress z 0.2": np.diag([1.0, 1.0, 0.2]),
        "stretch x 1.5": np.diag([1.5, 1.0, 1.0]),
        "stretch x 2.0": np.diag([2.0, 1.0, 1.0]),
        "shear xz 0.5": np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    }
    meshes = [("structured", structured_box((1, 1, 1), (0, 0, 0), 0.25)),
              ("gmsh-box", gmsh_box((1, 1, 1), (0, 0, 0), 0.25))]
    print("   columns: exact / altitude estimate per model; 'nodal': linear-model exact / nodal bound at x")
    print(f"{'mesh':<11} {'deformation':<15} {'nu':>5} " + " ".join(f"{m:>10}" for m in MODELS) + f" {'nodal':>7}")
    per_model = defaultdict(list)
    for kind, (points, tets) in meshes:
        mesh = checked_mesh(points, tets, kind)
        for label, A in deformations.items():
            x = mesh.points @ A.T
            for nu in ((0.3, 0.49) if quick else (0.3, 0.45, 0.49)):
                ratios = []
                nodal = None
                for model_name in MODELS:
                    exact, estimate, bound = measure(scene_for(model_name, 1e7, nu), mesh, x=x,
                                                     with_bound=(nodal is None))
                    ratios.append(exact / estimate)
                    per_model[model_name].append(exact / estimate)
                    if nodal is None:
                        nodal = exact / bound
                print(f"{kind:<11} {label:<15} {nu:5.2f} " + " ".join(f"{r:10.4f}" for r in ratios)
                      + f" {nodal:7.3f}", flush=True)
    print("\n-- deformed: exact / deformed-altitude estimate, per model --")
    for model_name in MODELS:
        print(summary_line(model_name, per_model[model_name]))


def ground_table():
    print("\n== Penalty ground (every boundary vertex's spring at its bound, exact includes it) ==")
    for kind, (points, tets) in (("structured", structured_box((1, 1, 1), (0, 0, 0), 0.125)),
                                 ("gmsh-box", gmsh_box((1, 1, 1), (0, 0, 0), 0.125))):
        mesh = checked_mesh(points, tets, kind)
        for stiffness in (1e6, 1e8, 1e10):
            scene = scene_for("neohookean", 1e6, 0.45, ground={"height": 0.0, "stiffness": stiffness})
            exact, estimate, bound = measure(scene, mesh)
            print(f"{kind:<11} E=1e6 ground {stiffness:8.0e} Pa/m: exact {exact:.4e} s, estimate {estimate:.4e} s, "
                  f"ratio {exact / estimate:.3f}, exact / nodal-bound step {exact / bound:.3f}")


def timing_table():
    print(f"\n== Cost of exact_stable_step (numba threads: {numba.get_num_threads()}) ==")
    for target in (10_000, 100_000):
        for kind in ("structured", "gmsh-box"):
            if kind == "structured":
                h = (0.25 * 0.25 * 5.0 / target) ** (1.0 / 3.0)
                points, tets = structured_box((1.0, 0.25, 0.25), (0, 0, 0), h)
            else:
                h = (0.25 * 0.25 * 5.2 / target) ** (1.0 / 3.0)
                points, tets = gmsh_box((1.0, 0.25, 0.25), (0, 0, 0), h)
            mesh = checked_mesh(points, tets, kind)
            scene = scene_for("stvk", 1e7, 0.45, fixed=[{"min": [-1e-6, -1, -1], "max": [1e-6, 1, 1]}])
            model = build_model(scene, mesh)
            frequency_analysis(model, iterations=2)                 # compile / load the kernels
            start = time.perf_counter()
            for _ in range(10):
                elastic_forces(model.rest_points, model.tets, model.Dm_inv, model.rest_volume, model.material_id,
                               model.lam, model.mu, model.csr_offsets, model.csr_slots)
            force_ms = (time.perf_counter() - start) / 10 * 1e3
            start = time.perf_counter()
            result = frequency_analysis(model)
            exact_s = time.perf_counter() - start
            start = time.perf_counter()
            nodal_frequency_bound(model)
            nodal_s = time.perf_counter() - start
            # a re-check on a deformed state (stretched by 5 %, bent), and a much tighter reference
            p = model.rest_points
            x = p * np.array([1.05, 1.0, 1.0]) + np.stack([0 * p[:, 0], 0 * p[:, 0], 0.01 * p[:, 0] ** 2], axis=1)
            start = time.perf_counter()
            deformed = frequency_analysis(model, x)
            deformed_s = time.perf_counter() - start
            tight = frequency_analysis(model, x, tol=1e-8, iterations=2000)
            print(f"{kind:<11} {model.tet_count:>7} tets: exact {exact_s:5.2f} s ({result.matvecs} operator "
                  f"applications); deformed {deformed_s:5.2f} s ({deformed.matvecs}; vs tol 1e-8: "
                  f"{deformed.lambda_max / tight.lambda_max - 1:.0e}); one force evaluation {force_ms:.1f} ms; "
                  f"nodal bound {nodal_s:.2f} s", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer meshes and moduli")
    parser.add_argument("--skip-timing", action="store_true")
    args = parser.parse_args()
    young = (1e5, 2e11) if args.quick else YOUNG
    started = time.perf_counter()
    print(f"AUTO_SAFETY today: {AUTO_SAFETY}")
    meshes = mesh_catalogue(args.quick)
    everything, nodal, everything_by_kind = rest_table(meshes, young)
    beam = steel_beam_table()
    deformed_table(args.quick)
    ground_table()
    if not args.skip_timing:
        timing_table()
    low, high = min(everything), max(everything)
    print("\n== Verdict ==")
    for label, kinds in (("structured + gmsh (no perturbed)", lambda k: k != "perturbed"),):
        subset = [r for (k, _), values in everything_by_kind.items() if kinds(k) for r in values]
        print(f"{label}: exact / altitude estimate in [{min(subset):.3f}, {max(subset):.3f}]: "
              + ("one factor fits" if max(subset) / 2 <= min(subset) else "no single factor fits"))
    print(f"exact / altitude estimate over all rest cases: min {low:.3f}, max {high:.3f} (spread {high / low:.2f}x)")
    print(f"a factor s is safe everywhere iff s <= {low:.3f}; the limit is within 2x of auto everywhere iff "
          f"s >= {high / 2:.3f}: " + ("one factor satisfies both" if high / 2 <= low else "no single factor does"))
    print(f"steel beam ratios: {', '.join(f'{r:.3f}' for r in beam)}")
    print(f"exact / nodal-bound step: min {min(nodal):.3f}, max {max(nodal):.3f}")
    print(f"total {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
