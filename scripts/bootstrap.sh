#!/usr/bin/env bash
# Idempotent set-up of everything petsoft needs, used by both README commands.
#
#   bash scripts/bootstrap.sh        # installs what is missing, skips what is done
#
# 1. Debian packages: PETSc 3.18 with petsc4py/slepc4py (real scalars, MUMPS, hypre, HDF5),
#    mpi4py, Debian's MPI-enabled h5py, OpenMPI, a C compiler, the Python headers,
#    chromium (the test suite renders report.html in it), DOLFINx 0.5 (the benchmarks'
#    cross-checks against it, run by the test suite) and gmsh (the independent cases' meshes).
#    (Installed only when missing; needs root, or sudo.)
# 2. A virtual environment at .venv made from /usr/bin/python3 with the system site packages,
#    so Debian's petsc4py/mpi4py/h5py are used (PyPI's would compile PETSc for half an hour or
#    bring a second HDF5 library into the process).
# 3. `pip install -e .[test]` with numpy pinned to the system's (numpy 2 breaks petsc4py 3.18);
#    redone only when pyproject.toml, CMakeLists.txt or the C kernels change.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
PACKAGES=(python3-petsc4py-real python3-slepc4py-real python3-mpi4py python3-h5py-mpi
          python3-matplotlib python3-numpy python3-scipy python3-sympy python3-tomlkit python3-venv python3-dev python3-pip
          openmpi-bin libopenmpi-dev build-essential
          chromium              # renders report.html headless in the test suite (tests/test_report_html.py)
          python3-dolfinx-real  # the benchmarks' DOLFINx cross-checks (tests/test_bench_scripts.py)
          python3-gmsh)         # the independent cases' shapes (scripts/benchmarks/independent, tests/test_truth_mesh_grading.py)

log() { echo "[bootstrap] $*"; }

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  log "installing Debian packages: ${missing[*]}"
  SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || { echo "[bootstrap] error: need root (or sudo) to apt-get install: ${missing[*]}" >&2; exit 1; }
    SUDO=sudo
  fi
  $SUDO apt-get update -q
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
else
  log "Debian packages present"
fi

if [ ! -x "$VENV/bin/python" ]; then
  log "creating $VENV from /usr/bin/python3 (with system site packages)"
  /usr/bin/python3 -m venv --system-site-packages "$VENV"
fi

# Debian's petsc4py/slepc4py live under PETSC_DIR/SLEPC_DIR, which Debian's .pth files only find
# through the /usr/lib/petsc link (installed with petsc-dev) or PETSC_DIR. A .pth of our own in
# the venv makes `import petsc4py` work with neither.
SITE="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')"
PETSC_PY=$(ls -d /usr/lib/petscdir/petsc3.*/x86_64-linux-gnu-real/lib/python3/dist-packages 2>/dev/null | sort -V | tail -1 || true)
SLEPC_PY=$(ls -d /usr/lib/slepcdir/slepc3.*/x86_64-linux-gnu-real/lib/python3/dist-packages 2>/dev/null | sort -V | tail -1 || true)
[ -n "$PETSC_PY" ] || { echo "[bootstrap] error: no real-scalar petsc4py found under /usr/lib/petscdir" >&2; exit 1; }
printf '%s\n%s\n' "$PETSC_PY" "$SLEPC_PY" > "$SITE/petsoft-debian-petsc.pth"

NUMPY_VERSION="$(/usr/bin/python3 -c 'import numpy; print(numpy.__version__)')"
echo "numpy==$NUMPY_VERSION" > "$VENV/constraints.txt"

STAMP="$VENV/.petsoft-install-stamp"
digest="$(cd "$ROOT" && find pyproject.toml CMakeLists.txt petsoft/fem/kernels/csrc petsoft/mesh/csrc -type f -print0 | sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1)"
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$digest" ] || ! "$VENV/bin/python" -c "import petsoft.fem.kernels._ckernels, petsoft.mesh._cmesh" 2>/dev/null; then
  log "pip install -e .[test] (numpy pinned to $NUMPY_VERSION)"
  PIP_CONSTRAINT="$VENV/constraints.txt" "$VENV/bin/python" -m pip install -q --disable-pip-version-check -e "$ROOT[test]"
  echo "$digest" > "$STAMP"
else
  log "petsoft already installed in $VENV"
fi
"$VENV/bin/python" -c "from petsc4py import PETSc; import mpi4py, h5py, numpy; print('[bootstrap] ready: PETSc', '.'.join(map(str, PETSc.Sys.getVersion())), 'numpy', numpy.__version__)"
