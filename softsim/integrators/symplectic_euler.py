"""Symplectic (semi-implicit) Euler, the whole step loop between two frames in compiled code.

One step, for every vertex ``i`` (Sifakis & Barbic 2012, section 6):

    v_i += dt * (f_i / m_i + a_ext_i)        elastic force, gravity and tractions
    ground contact (only with a ground): penalty pressure on the vertex's downward area, friction
    v_i *= damping_factor                    (only with damping)
    x_i += dt * v_i
    held components: v = prescribed velocity, x = start + velocity * t

Features a scene does not use cost nothing: ``ground`` and ``damping_factor`` are ``None`` then,
and Numba compiles (and caches) a separate specialisation of ``advance`` in which those branches
are pruned away.  Each step evaluates the corner forces of every tet in parallel, then gathers
them per vertex in a fixed order (deterministic results).
"""

from numba import prange

from ..kernels.forces import gather_vertex_force, tet_corner_forces
from ..kernels.jit import njit, njit_parallel


@njit
def downward_area(x, faces, face_offsets, face_slots, i):
    """Area [m^2] of vertex ``i``'s share of its boundary faces, projected on the ground and facing it.

    A third of each adjacent face's current area vector ``1/2 (x1 - x0) x (x2 - x0)`` (outward);
    only the part pointing down (-z) counts, so side faces add nothing and a flat bottom face gives
    exactly its area.
    """
    area_z = 0.0
    for k in range(face_offsets[i], face_offsets[i + 1]):
        f = face_slots[k] // 3
        a = faces[f, 0]
        b = faces[f, 1]
        c = faces[f, 2]
        ux = x[b, 0] - x[a, 0]
        uy = x[b, 1] - x[a, 1]
        wx = x[c, 0] - x[a, 0]
        wy = x[c, 1] - x[a, 1]
        area_z += (ux * wy - uy * wx) / 6.0
    return max(0.0, -area_z)


@njit
def ground_contact(x, v, i, dt, inv_mass, ground):
    """Apply the ground's penalty force and friction to ``v[i]`` in place.

    ground: ``(height [m], stiffness [Pa/m], friction, faces (b, 3), face_offsets, face_slots)``.
    The half-space ``z < height`` pushes with pressure ``stiffness * depth`` on the vertex's
    downward area; friction removes at most ``friction`` times the normal velocity change of
    tangential speed (it can stop a sliding vertex, never reverse it).
    """
    height, stiffness, friction, faces, face_offsets, face_slots = ground
    depth = height - x[i, 2]
    if depth <= 0.0:
        return
    area = downward_area(x, faces, face_offsets, face_slots, i)
    dv_normal = dt * stiffness * depth * area * inv_mass[i]
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


@njit
def move_vertex(x, v, i, dt, t_next, held, held_start, held_velocity):
    """``x[i] += dt v[i]``; held components follow ``start + velocity * t_next`` exactly."""
    for k in range(3):
        if held[i, k]:
            v[i, k] = held_velocity[i, k]
            x[i, k] = held_start[i, k] + held_velocity[i, k] * t_next
        else:
            x[i, k] += dt * v[i, k]


@njit_parallel
def advance(x, v, step_start, step_count, dt,
            tets, Dm_inv, rest_volume, model, lam, mu, offsets, slots, corner_forces,
            inv_mass, external_accel, held, held_start, held_velocity,
            ground, damping_factor):
    """Advance positions ``x`` and velocities ``v`` (node_count, 3) [m, m/s] in place by ``step_count`` steps.

    step_start: index of the first step (time ``step_start * dt`` [s]); dt [s].
    tets (m, 4), Dm_inv (m, 3, 3) [1/m], rest_volume (m,) [m^3]; model id and Lame lam, mu [Pa].
    offsets (n+1,), slots (4m,): vertex -> (tet, corner) CSR; corner_forces (m, 4, 3): work buffer.
    inv_mass (n,) [1/kg]; external_accel (n, 3) [m/s^2]: gravity plus tractions / mass.
    held (n, 3) bool; held_start, held_velocity (n, 3) [m, m/s]: prescribed motion of held components.
    ground: None, or the tuple ``ground_contact`` takes; damping_factor: None, or exp(-damping dt).
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
            if ground is not None:
                ground_contact(x, v, i, dt, inv_mass, ground)
            if damping_factor is not None:
                v[i, 0] *= damping_factor
                v[i, 1] *= damping_factor
                v[i, 2] *= damping_factor
            if ground is None:   # contact reads neighbours' positions: move them in a second pass
                move_vertex(x, v, i, dt, t_next, held, held_start, held_velocity)
        if ground is not None:
            for i in prange(node_count):
                move_vertex(x, v, i, dt, t_next, held, held_start, held_velocity)
