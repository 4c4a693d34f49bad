"""The peers of the performance issue, stepping the same beam: Taichi and Warp on the CPU.

- Taichi 1.7, CPU backend, ``cpu_max_num_threads=2``, float64: the fem128 style, the state in
  fields and one kernel per step that clears the forces, computes each tet's StVK forces and
  ``atomic_add``s them to its corners, then moves the vertices.
- Warp, CPU backend (one thread): the documented kernel style, an element kernel with
  ``wp.atomic_add`` scatter and an integration kernel, launched every step (recorded launches),
  compiled with ``WARP_CPU_COMPILER_FLAGS``.

Both compute ``H = -V0 P(F) Dm^-T`` with StVK ``P = F (lam tr(E) I + 2 mu E)``, symplectic Euler
``v += dt (f / m + g)``, ``x += dt v``, held vertices at rest: the same system as softsim, so
positions after many steps agree to round-off (the atomics sum in a different order).
Each class is importable only where its package is installed (``pip install ".[peers]"``).
"""

import numpy as np


def available():
    """``{name: reason or None}``: None where the peer can run, else why it is skipped."""
    out = {}
    for name, module in (("taichi", "taichi"), ("warp", "warp")):
        try:
            __import__(module)
            out[name] = None
        except Exception as exc:  # noqa: BLE001 - any import failure means: skip this peer
            out[name] = f"{module} not importable ({type(exc).__name__}); pip install '.[peers]'"
    return out


# ---------------------------------------------------------------------------------------------
# Taichi

_ti_kernel = None


def _taichi_kernel(threads):
    global _ti_kernel
    if _ti_kernel is not None:
        return _ti_kernel
    import taichi as ti

    ti.init(arch=ti.cpu, cpu_max_num_threads=threads, default_fp=ti.f64, default_ip=ti.i32,
            log_level=ti.ERROR, offline_cache=True)
    vec3 = ti.types.vector(3, ti.f64)
    mat3 = ti.types.matrix(3, 3, ti.f64)

    # Fields passed as templates, as fem128 keeps its state in fields: the kernel is compiled once
    # per set of fields (one per mesh).  The same kernel over ndarray arguments ran 0.75x as fast
    # at 10k tets, 0.9x at 100k, the same at 1M (interleaved, one process).
    @ti.kernel
    def substep(x: ti.template(), v: ti.template(), f: ti.template(), tets: ti.template(),
                Dm_inv: ti.template(), vol: ti.template(), inv_mass: ti.template(), held: ti.template(),
                gx: ti.f64, gy: ti.f64, gz: ti.f64, dt: ti.f64, lam: ti.f64, mu: ti.f64):
        for i in f:
            f[i] = vec3(0.0, 0.0, 0.0)
        for e in tets:
            t = tets[e]
            x0 = x[t[0]]
            Ds = mat3([[x[t[1]][0] - x0[0], x[t[2]][0] - x0[0], x[t[3]][0] - x0[0]],
                       [x[t[1]][1] - x0[1], x[t[2]][1] - x0[1], x[t[3]][1] - x0[1]],
                       [x[t[1]][2] - x0[2], x[t[2]][2] - x0[2], x[t[3]][2] - x0[2]]])
            B = Dm_inv[e]
            F = Ds @ B
            I = ti.Matrix.identity(ti.f64, 3)
            E = 0.5 * (F.transpose() @ F - I)
            S = 2.0 * mu * E + lam * E.trace() * I
            H = -vol[e] * (F @ S) @ B.transpose()
            f0 = vec3(0.0, 0.0, 0.0)
            for c in ti.static(range(3)):
                fc = vec3(H[0, c], H[1, c], H[2, c])
                ti.atomic_add(f[t[c + 1]], fc)
                f0 -= fc
            ti.atomic_add(f[t[0]], f0)
        for i in x:
            if held[i] != 0:
                v[i] = vec3(0.0, 0.0, 0.0)
            else:
                v[i] += dt * (f[i] * inv_mass[i] + vec3(gx, gy, gz))
                x[i] += dt * v[i]

    _ti_kernel = (ti, substep)
    return _ti_kernel


class Taichi:
    """The beam's state in Taichi fields of its own (an SNode tree a mesh, about 110 B a tet, freed
    by ``close``)."""
    name = "taichi"

    def __init__(self, arrays, threads=2):
        ti, self.kernel = _taichi_kernel(threads)
        self.ti = ti
        a = arrays
        vertices, tets = len(a["x"]), len(a["tets"])
        self.x, self.v, self.f = (ti.Vector.field(3, ti.f64) for _ in range(3))
        self.inv_mass, self.held = ti.field(ti.f64), ti.field(ti.i32)
        self.tets, self.Dm_inv, self.vol = ti.Vector.field(4, ti.i32), ti.Matrix.field(3, 3, ti.f64), ti.field(ti.f64)
        builder = ti.FieldsBuilder()
        for field in (self.x, self.v, self.f, self.inv_mass, self.held):
            builder.dense(ti.i, vertices).place(field)
        for field in (self.tets, self.Dm_inv, self.vol):
            builder.dense(ti.i, tets).place(field)
        self.fields = builder.finalize()
        self.x.from_numpy(a["x"])
        self.v.from_numpy(a["v"])
        self.f.fill(0.0)
        self.inv_mass.from_numpy(a["inv_mass"])
        self.held.from_numpy(a["held"])
        self.tets.from_numpy(a["tets"])
        self.Dm_inv.from_numpy(a["Dm_inv"])
        self.vol.from_numpy(a["rest_volume"])
        self.g = tuple(float(c) for c in a["gravity"])
        self.dt, self.lam, self.mu = a["dt"], a["lam"], a["mu"]
        self.tet_count = tets

    def run(self, steps):
        for _ in range(steps):
            self.kernel(self.x, self.v, self.f, self.tets, self.Dm_inv, self.vol, self.inv_mass, self.held,
                        *self.g, self.dt, self.lam, self.mu)
        self.ti.sync()

    def positions(self):
        return self.x.to_numpy()

    def close(self):
        """Free the fields (Taichi keeps an SNode tree until it is destroyed or the process ends)."""
        self.fields.destroy()


# ---------------------------------------------------------------------------------------------
# Warp

_wp_kernels = None
# Clang's flags for the peer's kernels (this module's): the host's instruction set, -O3, and fused
# multiply-adds as softsim's kernels have them (``fastmath={"contract"}``), nothing else of
# fast-math.  Warp 1.19's default adds LLVM options for more inlining and a shallower SLP
# vectoriser (``warp.config.cpu_compiler_flags``).  AVX-512 Xeon, 100k-tet beam, M tet-steps/s:
# the default 33.2, ``-march=native`` alone 38.1, with -O3 38.6, with contraction too 39.9 (1.20x;
# 10k 34.8 -> 39.5, 1M 26.3 -> 30.0); Warp's ``optimization_level`` 3 (its back end's; 2 by
# default on the CPU) 40.1 against 39.7.  With -ffast-math it ran 43.2, reassociating as softsim
# does not.
WARP_CPU_COMPILER_FLAGS = "-march=native -O3 -ffp-contract=fast"


def _warp_kernels():
    global _wp_kernels
    if _wp_kernels is not None:
        return _wp_kernels
    import warp as wp

    wp.config.quiet = True
    wp.init()
    wp.set_module_options({"cpu_compiler_flags": WARP_CPU_COMPILER_FLAGS, "optimization_level": 3})

    @wp.kernel
    def eval_tets(x: wp.array(dtype=wp.vec3d), tets: wp.array(dtype=wp.int32, ndim=2),
                  Dm_inv: wp.array(dtype=wp.mat33d), vol: wp.array(dtype=wp.float64),
                  lam: wp.float64, mu: wp.float64, f: wp.array(dtype=wp.vec3d)):
        e = wp.tid()
        i0 = tets[e, 0]
        i1 = tets[e, 1]
        i2 = tets[e, 2]
        i3 = tets[e, 3]
        x0 = x[i0]
        Ds = wp.matrix_from_cols(x[i1] - x0, x[i2] - x0, x[i3] - x0)
        B = Dm_inv[e]
        F = Ds * B
        I = wp.identity(n=3, dtype=wp.float64)
        E = wp.float64(0.5) * (wp.transpose(F) * F - I)
        S = wp.float64(2.0) * mu * E + lam * wp.trace(E) * I
        H = -vol[e] * (F * S) * wp.transpose(B)
        h1 = wp.vec3d(H[0, 0], H[1, 0], H[2, 0])
        h2 = wp.vec3d(H[0, 1], H[1, 1], H[2, 1])
        h3 = wp.vec3d(H[0, 2], H[1, 2], H[2, 2])
        wp.atomic_add(f, i1, h1)
        wp.atomic_add(f, i2, h2)
        wp.atomic_add(f, i3, h3)
        wp.atomic_add(f, i0, -(h1 + h2 + h3))

    @wp.kernel
    def integrate(x: wp.array(dtype=wp.vec3d), v: wp.array(dtype=wp.vec3d), f: wp.array(dtype=wp.vec3d),
                  inv_mass: wp.array(dtype=wp.float64), held: wp.array(dtype=wp.int32), g: wp.vec3d,
                  dt: wp.float64):
        i = wp.tid()
        if held[i] != 0:
            v[i] = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
        else:
            v[i] = v[i] + dt * (f[i] * inv_mass[i] + g)
            x[i] = x[i] + dt * v[i]
        f[i] = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))

    _wp_kernels = (wp, eval_tets, integrate)
    return _wp_kernels


class Warp:
    name = "warp"

    def __init__(self, arrays):
        wp, self.eval_tets, self.integrate = _warp_kernels()
        self.wp = wp
        a = arrays
        d = "cpu"
        self.x = wp.array(a["x"], dtype=wp.vec3d, device=d)
        self.v = wp.array(a["v"], dtype=wp.vec3d, device=d)
        self.f = wp.zeros(len(a["x"]), dtype=wp.vec3d, device=d)
        self.tets = wp.array(a["tets"], dtype=wp.int32, device=d)
        self.Dm_inv = wp.array(a["Dm_inv"], dtype=wp.mat33d, device=d)
        self.vol = wp.array(a["rest_volume"], dtype=wp.float64, device=d)
        self.inv_mass = wp.array(a["inv_mass"], dtype=wp.float64, device=d)
        self.held = wp.array(a["held"], dtype=wp.int32, device=d)
        self.g = wp.vec3d(*[float(c) for c in a["gravity"]])
        self.dt, self.lam, self.mu = wp.float64(a["dt"]), wp.float64(a["lam"]), wp.float64(a["mu"])
        self.tet_count = len(a["tets"])
        self.node_count = len(a["x"])
        # Launches recorded once and replayed (``record_cmd``, Warp's way to cut launch overhead):
        # 1.18x launching anew every step at 10k tets, 1.05x at 100k (interleaved, one process).
        self.launches = (
            wp.launch(self.eval_tets, dim=self.tet_count, device=d, record_cmd=True,
                      inputs=[self.x, self.tets, self.Dm_inv, self.vol, self.lam, self.mu, self.f]),
            wp.launch(self.integrate, dim=self.node_count, device=d, record_cmd=True,
                      inputs=[self.x, self.v, self.f, self.inv_mass, self.held, self.g, self.dt]))

    def run(self, steps):
        forces, update = self.launches
        for _ in range(steps):
            forces.launch()
            update.launch()
        self.wp.synchronize_device("cpu")

    def positions(self):
        return self.x.numpy().astype(np.float64).reshape(-1, 3)
