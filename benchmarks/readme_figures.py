"""Make the README's pictures in docs/images/ (they are generated, not kept in git).

    python benchmarks/readme_figures.py [--quick]

Runs the example scenes and the commands the README shows: the bouncing cube as a GIF and the
cantilever's von Mises frame (``softsim render``), the cantilever sweep's plot (``softsim sweep
--plot``), the cantilever's error against wall time (``softsim verify --case cantilever`` on one
thread: 91 s on an idle AMD EPYC, ``--quick`` for the quick ladder) and the stability report's
plot of the measured limit against ``dt: auto`` (``softsim stability --quick``, about a minute).  The benchmark table and plot come
from ``python -m benchmarks`` (benchmarks/results/).  Needs ``pip install -e ".[plot,sweep]"``.
"""

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"


def softsim(*args, cwd):
    subprocess.run([sys.executable, "-m", "softsim.cli.main", *map(str, args)], cwd=cwd, check=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the quick verification ladder")
    args = parser.parse_args()
    IMAGES.mkdir(parents=True, exist_ok=True)
    configs = ROOT / "configs"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        softsim("run", configs / "bouncing_cube.yaml", cwd=work)
        softsim("render", "bouncing_cube.h5", "-o", IMAGES / "bouncing_cube.gif", "--frames", "::2",
                "--size", "400x300", "--field", "speed", "--no-edges", cwd=work)
        softsim("run", configs / "cantilever.yaml", cwd=work)
        softsim("render", "cantilever.h5", "-o", IMAGES / "cantilever_von_mises.png", "--frame", "9",
                "--size", "800x450", cwd=work)
        softsim("sweep", configs / "cantilever_sweep.yaml", "-o", "sweep",
                "--plot", "youngs_modulus:tip_displacement:poissons_ratio", cwd=work)
        shutil.copy(work / "sweep" / "summary.png", IMAGES / "sweep_cantilever.png")
        softsim("verify", *(["--quick"] if args.quick else []), "--case", "cantilever", "--threads", "1", "-o", "verify",
                cwd=work)
        shutil.copy(work / "verify" / "verify_cantilever.png", IMAGES / "verify_cantilever.png")
        softsim("stability", "--quick", "-o", "stability", cwd=work)
        shutil.copy(work / "stability" / "stability.png", IMAGES / "stability.png")
    print(f"wrote {', '.join(sorted(p.name for p in IMAGES.iterdir()))} in {IMAGES}")


if __name__ == "__main__":
    main()
