"""``softsim info``: what a run file holds, as a dict (for ``--json``) and as text."""

import numpy as np

from ..io.fields import FIELDS
from ..io.hdf5 import wall_time_s
from .results import open_results


def summarize(path):
    """A JSON-ready summary of the run file ``path``.

    Keys: path, scene (mesh shape, material model, E [Pa], nu, density [kg/m^3], ground), tets,
    vertices, status, status_reason, steps, dt [s], wall_time_s, frames, time [s] (simulated time
    reached; None without a frame), duration [s] (planned), softsim_version, and fields: ``{name: {location, shape, unit,
    min, max}}`` with min / max over every frame (and every component) of each stored field.
    """
    with open_results(path, allow_empty=True) as results:
        attrs, scene = results.attrs, results.scene
        mesh, material = scene.get("mesh", {}) or {}, scene.get("material", {}) or {}
        summary = {
            "path": str(results.path),
            "scene": {
                "mesh": mesh.get("shape"),
                "model": material.get("model"),
                "youngs_modulus": material.get("youngs_modulus"),
                "poissons_ratio": material.get("poissons_ratio"),
                "density": material.get("density"),
                "ground": scene.get("ground") is not None,
            },
            "tets": results.tet_count,
            "vertices": results.node_count,
            "status": attrs.get("status"),
            "status_reason": attrs.get("status_reason", ""),
            "steps": attrs.get("steps"),
            "dt": attrs.get("dt"),
            "wall_time_s": wall_time_s(results.file),
            "frames": results.frame_count,
            "time": float(results.times[-1]) if results.frame_count else None,
            "duration": (scene.get("time", {}) or {}).get("duration"),
            "softsim_version": attrs.get("softsim_version"),
            "fields": {},
        }
        for name in results.fields:
            spec = FIELDS[name]
            for dataset in spec.datasets:
                lo, hi = _range(results, dataset)
                summary["fields"][dataset] = {"location": spec.location, "shape": list(spec.shape),
                                              "unit": spec.unit, "min": lo, "max": hi}
    return summary


def _range(results, dataset):
    """(min, max) over the frames counted by ``io.hdf5.frames_written``, read one frame at a time;
    (None, None) without a frame."""
    data = results.file["frames"][dataset]
    k = results.frame_count
    if k == 0:
        return None, None
    if data.ndim == 1:
        values = data[:k]
        return float(values.min()), float(values.max())
    lo, hi = np.inf, -np.inf
    for i in range(k):
        frame = data[i]
        lo, hi = min(lo, float(frame.min())), max(hi, float(frame.max()))
    return lo, hi


def format_summary(summary):
    """The summary as aligned text lines for a terminal."""
    scene = summary["scene"]
    material = (f"{scene['model']}, E {scene['youngs_modulus']:.4g} Pa, nu {scene['poissons_ratio']}, "
                f"density {scene['density']:.4g} kg/m^3" if scene["model"] else "unknown")
    status = summary["status"] + (f" ({summary['status_reason']})" if summary["status_reason"] else "")
    duration = f" of {summary['duration']:.6g} s" if summary["duration"] else ""
    rows = [
        ("file", summary["path"]),
        ("scene", f"{scene['mesh']} mesh, {material}" + (", ground" if scene["ground"] else "")),
        ("mesh", f"{summary['tets']} tets, {summary['vertices']} vertices"),
        ("status", status),
        ("steps", f"{summary['steps']} of dt = {summary['dt']:.4g} s, wall time {summary['wall_time_s']:.3g} s"),
        ("frames", f"{summary['frames']}, simulated time reached {summary['time']:.6g} s{duration}"
                   if summary["frames"] else "none"),
    ]
    lines = [f"{key:<8} {value}" for key, value in rows]
    if summary["fields"]:
        lines.append("fields   name                        where    unit         min          max")
        for name, info in summary["fields"].items():
            shape = "x".join(str(d) for d in info["shape"])
            where = info["location"] + (f" {shape}" if shape else "")
            lo, hi = ("-", "-") if info["min"] is None else (f"{info['min']:.4g}", f"{info['max']:.4g}")
            lines.append(f"         {name:<27} {where:<8} {info['unit']:<5} {lo:>12} {hi:>12}")
    else:
        lines.append("fields   none (output.fields was empty)")
    return lines
