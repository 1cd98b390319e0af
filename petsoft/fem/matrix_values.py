"""Writing an AIJ matrix's values in place (PETSc's ``MatSeqAIJGetArray``): a sequential one's,
and a parallel one's diagonal and off-diagonal blocks (``MatMPIAIJGetSeqAIJ``).

petsc4py 3.18 has no binding for the value array of an AIJ matrix, so an assembled CSR value array
reaches PETSc through ``MatSetValues`` (a search per entry: 30 ns an entry, 0.3 ms a Jacobian of
a 351-dof bar, as much as the element kernels). When the matrix is sequential and its nonzeros are
exactly the assembler's pattern (sorted CSR, same count), its value array *is* laid out as the
assembler's, and one copy replaces the insertion. The functions are taken from the PETSc library
petsc4py already loaded (by ctypes; ``MatSeqAIJRestoreArray`` marks the matrix changed, so solvers
refactor it). Where the library cannot be found the caller keeps the generic path.

In parallel (:class:`ParallelValues`) every local value's place is found once: in this rank's
diagonal or off-diagonal block for an owned row, else on the rank owning the row, which receives
it by one ``Alltoallv`` a matrix and adds it in. ``MatSetValuesLocal`` searched every entry and
stashed the ghost rows': 23 ms of a 41 ms Jacobian on 2 ranks (27,300 dofs).
"""

from __future__ import annotations

import ctypes
from functools import lru_cache

import numpy as np
from petsc4py import PETSc

from petsoft.fem.kernels.scatter import csr_find, csr_find_local

__all__ = ["ParallelValues", "copy_into_seqaij", "seqaij_available"]


@lru_cache(maxsize=1)
def _petsc_library():
    """The loaded PETSc shared library (the one petsc4py uses), or None."""
    try:
        with open("/proc/self/maps") as maps:
            paths = [line.split()[-1] for line in maps if "libpetsc" in line]
    except OSError:
        return None
    for path in paths:
        if path.startswith("/"):
            lib = ctypes.CDLL(path)
            for name in ("MatSeqAIJGetArray", "MatSeqAIJRestoreArray"):
                fn = getattr(lib, name)
                fn.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p)]
                fn.restype = ctypes.c_int
            fn = lib.MatMPIAIJGetSeqAIJ
            fn.argtypes = [ctypes.c_void_p] + [ctypes.POINTER(ctypes.c_void_p)] * 3
            fn.restype = ctypes.c_int
            return lib
    return None


def seqaij_available() -> bool:
    """Whether in-place writes are possible in this process."""
    return PETSc.ScalarType is np.float64 and _petsc_library() is not None


def copy_into_seqaij(A: PETSc.Mat, values: np.ndarray) -> bool:
    """Copy ``values`` into the value array of the sequential AIJ matrix ``A`` in place.

    The caller guarantees that ``A``'s nonzero structure is its pattern (the same sorted CSR);
    this checks the type and the count of nonzeros and returns False (nothing written) when
    they do not match, so the caller can insert the values the generic way.
    """
    lib = _petsc_library()
    if lib is None or A.getType() != PETSc.Mat.Type.SEQAIJ:
        return False
    if int(A.getInfo()["nz_used"]) != len(values):
        return False
    ptr = ctypes.c_void_p()
    handle = ctypes.c_void_p(A.handle)
    if lib.MatSeqAIJGetArray(handle, ctypes.byref(ptr)) or not ptr.value:
        return False
    target = np.ctypeslib.as_array((ctypes.c_double * len(values)).from_address(ptr.value))
    target[:] = values
    # (the restore increases the matrix's state: a solver set up on it refactors)
    if lib.MatSeqAIJRestoreArray(handle, ctypes.byref(ptr)):
        raise PETSc.Error(1)
    return True


def _write_seqaij(lib, handle: ctypes.c_void_p, n: int, fill) -> None:
    """``fill(target)`` on the n values of the sequential AIJ matrix ``handle``, in place."""
    ptr = ctypes.c_void_p()
    if lib.MatSeqAIJGetArray(handle, ctypes.byref(ptr)):
        raise PETSc.Error(1)
    if n:
        fill(np.ctypeslib.as_array((ctypes.c_double * n).from_address(ptr.value)))
    if lib.MatSeqAIJRestoreArray(handle, ctypes.byref(ptr)):
        raise PETSc.Error(1)


class ParallelValues:
    """Where the values of an assembler's local pattern go in a parallel AIJ matrix whose
    nonzeros are the union of every rank's pattern (made so by the assembler), found once.

    Parameters
    ----------
    A : PETSc.Mat
        The MPIAIJ matrix, assembled, with its final structure (collective).
    indptr, indices : ndarray
        The assembler's local scalar CSR (local rows and columns), in whose order the values
        come.
    dof : ndarray (nlocal,) int64
        Global scalar number of each local one.
    nowned : int
        Local rows owned here: the first ``nowned`` (the others go to their owners).
    """

    def __init__(self, A: PETSc.Mat, indptr: np.ndarray, indices: np.ndarray, dof: np.ndarray,
                 nowned: int):
        from mpi4py import MPI

        self.comm = A.getComm().tompi4py()
        rstart = A.getOwnershipRange()[0]
        cstart, cend = A.getOwnershipRangeColumn()
        ai, aj, _ = A.getValuesCSR()
        ai, aj = np.asarray(ai, np.int64), np.asarray(aj, np.int64)
        # this rank's entries in row-major order, each row's columns ascending: the diagonal
        # block holds the k-th diagonal entry at value k, the off-diagonal block likewise (its
        # compressed columns keep the global order)
        diagonal = (aj >= cstart) & (aj < cend)
        self.nnz = (int(diagonal.sum()), int((~diagonal).sum()))
        slot = np.empty(len(aj), dtype=np.int64)
        slot[diagonal] = np.arange(self.nnz[0])
        slot[~diagonal] = self.nnz[0] + np.arange(self.nnz[1])

        def checked(at):
            if len(at) and at.min() < 0:
                raise ValueError("the matrix lacks entries of the assembler's pattern")
            return slot[at]

        # the owned rows' values come first: found in place, no (nnz,) rows and columns
        indptr = np.asarray(indptr, dtype=np.int64)
        dof = np.asarray(dof, dtype=np.int64)
        nown = int(indptr[nowned])
        own_slots = checked(csr_find_local(ai, aj, rstart, indptr[:nowned + 1], indices, dof))
        ghost = np.arange(nown, int(indptr[-1]))
        ghost_rows = np.repeat(dof[nowned:len(indptr) - 1], np.diff(indptr[nowned:]))
        ghost_cols = dof[np.asarray(indices[nown:], dtype=np.int64)]
        # ghost rows: to their owners, ordered by rank
        starts = np.array(self.comm.allgather(rstart) + [int(A.getSize()[0])], dtype=np.int64)
        owner = np.searchsorted(starts, ghost_rows, side="right") - 1
        order = np.argsort(owner, kind="stable")
        self.send_values = ghost[order]
        self.send_counts = np.bincount(owner, minlength=self.comm.size).astype(np.int64)
        self.recv_counts = np.empty_like(self.send_counts)
        self.comm.Alltoall(self.send_counts, self.recv_counts)
        pairs = np.ascontiguousarray(np.column_stack([ghost_rows, ghost_cols])[order])
        received = np.empty((int(self.recv_counts.sum()), 2), dtype=np.int64)
        self.comm.Alltoallv([pairs, 2 * self.send_counts, MPI.INT64_T],
                            [received, 2 * self.recv_counts, MPI.INT64_T])
        recv_slots = checked(csr_find(ai, aj, received[:, 0] - rstart, received[:, 1]))
        # several ranks may send to one place: summed by reduceat over the sorted places
        self.recv_order = np.argsort(recv_slots, kind="stable")
        sorted_slots = recv_slots[self.recv_order]
        first = np.flatnonzero(np.r_[True, sorted_slots[1:] != sorted_slots[:-1]]
                               if len(sorted_slots) else np.zeros(0, bool))
        self.recv_starts, recv_slots = first, sorted_slots[first]
        # the places split by block, so that write() fills PETSc's arrays directly (a buffer of
        # every value, zeroed and copied at every assembly, was 88 MB a rank at 1M tets)
        # a received sum is added where this rank's own value was written, written elsewhere
        nd = self.nnz[0]
        self._own = _by_block(own_slots, np.arange(nown), nd)
        written = np.zeros(sum(self.nnz), dtype=bool)
        written[own_slots] = True
        also = written[recv_slots]
        index = np.arange(len(recv_slots))
        self._received_added = _by_block(recv_slots[also], index[also], nd)
        self._received_only = _by_block(recv_slots[~also], index[~also], nd)
        # the structure of the assembler's matrices is the union of the ranks' patterns, so
        # the values sent here and the ones received cover every place; a matrix given places
        # beyond it is left to the caller's generic insertion (write() returns False)
        written[recv_slots] = True
        self._covers_all = bool(written.all())
        self._mpi_double = MPI.DOUBLE

    def write(self, A: PETSc.Mat, values: np.ndarray) -> bool:
        """Replace ``A``'s values by the sums over ranks of the local ``values`` (collective).
        False (nothing written, on every rank) when the PETSc library cannot be reached, the
        matrix's nonzero count is not the one this was made for, or the matrix this was made
        from had places no rank's values reach."""
        lib = _petsc_library()
        fits = (lib is not None and self._covers_all and A.getType() == PETSc.Mat.Type.MPIAIJ
                and int(A.getInfo(PETSc.Mat.InfoType.LOCAL)["nz_used"]) == sum(self.nnz))
        if not self.comm.allreduce(fits, op=_land()):
            return False
        send = np.ascontiguousarray(values[self.send_values])
        recv = np.empty(int(self.recv_counts.sum()))
        self.comm.Alltoallv([send, self.send_counts, self._mpi_double],
                            [recv, self.recv_counts, self._mpi_double])
        summed = (np.add.reduceat(recv[self.recv_order], self.recv_starts) if len(recv)
                  else recv)
        blocks = [ctypes.c_void_p(), ctypes.c_void_p()]
        colmap = ctypes.c_void_p()
        if lib.MatMPIAIJGetSeqAIJ(ctypes.c_void_p(A.handle), ctypes.byref(blocks[0]),
                                  ctypes.byref(blocks[1]), ctypes.byref(colmap)):
            raise PETSc.Error(1)

        def fill(block):
            def write_block(target):
                slots, which = self._own[block]
                target[slots] = values[which]
                slots, which = self._received_only[block]
                target[slots] = summed[which]
                slots, which = self._received_added[block]
                target[slots] += summed[which]
            return write_block

        _write_seqaij(lib, blocks[0], self.nnz[0], fill(0))
        _write_seqaij(lib, blocks[1], self.nnz[1], fill(1))
        # the blocks' states rose; the matrix's rises with an assembly (nothing stashed)
        A.assemble()
        return True


def _by_block(slots: np.ndarray, which: np.ndarray, nd: int):
    """((slots, which) in the diagonal block, (slots - nd, which) in the off-diagonal one)."""
    d = slots < nd
    return (slots[d], which[d]), (slots[~d] - nd, which[~d])


def _land():
    from mpi4py import MPI

    return MPI.LAND
