/* Where entries sit in a CSR structure whose rows hold sorted columns: one bisection within a
 * row per entry. (numpy's searchsorted over one key per entry, row * ncols + column, took 1.1 s
 * of a 4 s first parallel assembly at 330k tets; this is linear in the entries times the log
 * of a row's length.) */
#include <stdint.h>

/* The index k in [ai[r], ai[r + 1]) with aj[k] == c, or -1 (also for r outside [0, nrows)). */
static int64_t find_in_row(int64_t r, int64_t c, int64_t nrows, const int64_t *ai,
                           const int64_t *aj) {
  if (r < 0 || r >= nrows) return -1;
  int64_t lo = ai[r], hi = ai[r + 1];
  while (lo < hi) {
    const int64_t mid = lo + (hi - lo) / 2;
    if (aj[mid] < c)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo < ai[r + 1] && aj[lo] == c ? lo : -1;
}

/* out[q] = k with aj[k] == col[q] and ai[row[q]] <= k < ai[row[q] + 1], or -1 when the row holds
 * no such column or row[q] is outside [0, nrows). */
void petsoft_csr_find(int64_t nq, const int64_t *row, const int64_t *col, int64_t nrows,
                      const int64_t *ai, const int64_t *aj, int64_t *out) {
  for (int64_t q = 0; q < nq; ++q) out[q] = find_in_row(row[q], col[q], nrows, ai, aj);
}

/* The same for every entry of a local CSR (rows 0..nrows-1 of indptr/indices, local numbers)
 * mapped to global numbers by dof: out[k] for indptr[0] <= k < indptr[nrows] is the index into
 * aj of (dof[i] - row0, dof[indices[k]]), with no (nnz,) temporaries of rows and columns. */
void petsoft_csr_find_local(int64_t nrows, const int64_t *indptr, const int64_t *indices,
                            const int64_t *dof, int64_t row0, int64_t arows, const int64_t *ai,
                            const int64_t *aj, int64_t *out) {
  for (int64_t i = 0; i < nrows; ++i) {
    const int64_t r = dof[i] - row0;
    for (int64_t k = indptr[i]; k < indptr[i + 1]; ++k)
      out[k - indptr[0]] = find_in_row(r, dof[indices[k]], arows, ai, aj);
  }
}
