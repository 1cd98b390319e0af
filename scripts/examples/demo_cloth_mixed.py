"""Cloth with mixed stiffness dropped on a sphere (the lecture notes' second cloth example, 000).

The cloth of ``demo_cloth_sphere.py`` with two materials: the springs of the half x < 0 are
``--stiff-factor`` (default 20) times stiffer than those of the other half (bending springs too).
The stiff half vibrates at a frequency sqrt(20) higher, so at the same step the methods' numerical
damping treats the two halves differently: backward Euler and semi-implicit flatten the stiff
half's vibrations much more than the soft half's, the midpoint rule keeps both (and conserves the
energy), and ERE resolves the stiff linear part exactly. Same table and checks as the sphere demo
(penetration tolerance, BE/SI energy never growing, cost per step Newton vs local/global).

Measured (defaults, 1 rank): largest penetration BE 2.8 mm, SI 3.1 mm, midpoint 8.7 mm, ERE
13 cm (it fails: it gains 140% of the energy scale once the stiff half hits the sphere); BE by
Newton 3.0 iterations and 79 ms per step, by local/global 246 iterations and 1.3 s per step
with 3 steps halved after 500 iterations (the stiff half makes the constant matrix a poor
model of the Hessian); the retried steps change the step sequence, and the two final states
then differ by 15 cm (the draping is sensitive).

Run::

    .venv/bin/python scripts/examples/demo_cloth_mixed.py --out cloth-mixed
    mpiexec -n 2 .venv/bin/python scripts/examples/demo_cloth_mixed.py --out cloth-mixed

Writes ``energy.png``, ``frames-<method>.png`` (stiff half red, soft half blue) and
``<method>/trajectory.xdmf`` per method.

Things to try:

* ``--stiff-factor 100``: a stiffer half (more local/global iterations: the global matrix,
  factored once, approximates the stiff springs' Hessian worse);
* ``--methods be be-lg -lg_anderson 0``: the plain local/global iteration of Liu et al.;
* ``--step 0.01 --methods be si``: the numerical damping of BE and SI at a large step;
* PETSc options for Newton (``-snes_monitor``, ``-ksp_type cg -pc_type gamg``) and for the
  local/global solver (``-lg_rtol``, ``-lg_max_it``, ``-lg_ksp_type``, ``-lg_pc_type``).
"""

from __future__ import annotations

import argparse
import sys

import petsc4py

import petsoft  # noqa: F401  before petsc4py.init: one BLAS thread (petsoft/__init__.py)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    from _cloth_common import add_arguments

    add_arguments(p, "cloth-mixed")
    p.add_argument("--stiff-factor", type=float, default=20.0,
                   help="stiffness of the x < 0 half relative to the x > 0 half")
    args, petsc_args = p.parse_known_args(argv)
    petsc4py.init([sys.argv[0], *petsc_args])
    import numpy as np
    from _cloth_common import cloth_mesh, compare

    def stiff_half(model):
        """Factor per spring: stiff where the spring's midpoint has x < 0."""
        pts = model.dmesh.mesh.points
        mid = 0.5 * (pts[model.edges[:, 0], 0] + pts[model.edges[:, 1], 0])
        return np.where(mid < 0.0, args.stiff_factor, 1.0)

    nodes = 7 if args.quick else args.nodes
    points, tris = cloth_mesh(nodes, 1.0, 0.45)
    # colour of each triangle: 1 in the stiff half
    colour = (points[tris, 0].mean(axis=1) < 0.0).astype(float)
    return compare(args, title=f"mixed-stiffness cloth (x < 0: {args.stiff_factor:g} x stiffer)",
                   stiffness_scale=stiff_half, colour=colour)


if __name__ == "__main__":
    raise SystemExit(main())
