"""Symplectic (semi-implicit) Euler, the whole step loop between two frames in compiled code.

One step, for every vertex ``i`` (Sifakis & Barbic 2012, section 6):

    v_i += dt * (f_i / m_i + a_ext_i)        elastic force, gravity and tractions
    ground contact (only if the scene has a ground): penalty normal force, Coulomb friction
    v_i *= damping_factor                    only if the scene has damping
    x_i += dt * v_i
    held components: v = prescribed velocity, x = start + velocity * t

The scene's features are flags: a branch that is false skips its whole pass, so a scene without
ground or damping does no work for them.  Each step evaluates the corner forces of every tet in
parallel, then gathers them per vertex in a fixed order (deterministic results).
"""

from numba import prange

from ..kernels.forces import gather_vertex_force, tet_corner_forces
from ..kernels.jit import njit, njit_parallel


@njit
def ground_contact(x, v, i, friction, height, contact_stiffness, inv_mass, dt):
    """Apply the ground's penalty force and friction to vertex ``i``'s velocity ``v[i]`` in place.

    Ground: the half-space ``z < height``.  Normal force ``k_i (height - z)`` [N] with
    ``k_i = contact_stiffness[i]`` [N/m]; friction removes at most ``friction * normal * dt / m``
    of tangential speed (it can stop a sliding vertex, never reverse it).
    """
    depth = height - x[i, 2]
    if depth <= 0.0:
        return
    dv_normal = dt * contact_stiffness[i] * depth * inv_mass[i]
    v[i, 2] += dv_normal
    if friction > 0.0:
        vt = (v[i, 0] ** 2 + v[i, 1] ** 2) ** 0.5
        dv_friction = friction * dv_normal
        if vt <= dv_friction:
            v[i, 0] = 0.0
            v[i, 1] = 0.0
        else:
            scale = 1.0 - dv_friction / vt
            v[i, 0] *= scale
            v[i, 1] *= scale


@njit_parallel
def advance(x, v, step_start, step_count, dt,
            tets, Dm_inv, rest_volume, model, lam, mu, offsets, slots, corner_forces,
            inv_mass, external_accel,
            held, held_start, held_velocity,
            has_ground, ground_height, ground_friction, contact_stiffness,
            has_damping, damping_factor):
    """Advance positions ``x`` and velocities ``v`` (node_count, 3) [m, m/s] in place by ``step_count`` steps.

    step_start: index of the first step (time ``step_start * dt`` [s]); dt [s].
    tets (m, 4), Dm_inv (m, 3, 3) [1/m], rest_volume (m,) [m^3]; model id and Lame lam, mu [Pa].
    offsets (n+1,), slots (4m,): vertex -> (tet, corner) CSR; corner_forces (m, 4, 3): work buffer.
    inv_mass (n,) [1/kg]; external_accel (n, 3) [m/s^2]: gravity plus tractions / mass.
    held (n, 3) bool; held_start, held_velocity (n, 3) [m, m/s]: prescribed motion of held components.
    contact_stiffness (n,) [N/m]; damping_factor = exp(-damping dt).
    """
    node_count = x.shape[0]
    for step in range(step_start, step_start + step_count):
        t_next = (step + 1) * dt
        for e in prange(tets.shape[0]):
            tet_corner_forces(x, tets, Dm_inv, rest_volume, e, model, lam, mu, corner_forces)
        for i in prange(node_count):
            fx, fy, fz = gather_vertex_force(corner_forces, offsets, slots, i)
            w = inv_mass[i]
            v[i, 0] += dt * (fx * w + external_accel[i, 0])
            v[i, 1] += dt * (fy * w + external_accel[i, 1])
            v[i, 2] += dt * (fz * w + external_accel[i, 2])
            if has_ground:
                ground_contact(x, v, i, ground_friction, ground_height, contact_stiffness, inv_mass, dt)
            if has_damping:
                v[i, 0] *= damping_factor
                v[i, 1] *= damping_factor
                v[i, 2] *= damping_factor
            for k in range(3):
                if held[i, k]:
                    v[i, k] = held_velocity[i, k]
                    x[i, k] = held_start[i, k] + held_velocity[i, k] * t_next
                else:
                    x[i, k] += dt * v[i, k]
