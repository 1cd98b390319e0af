/* Scatter-add of element vectors and element matrices into local arrays.
 *
 * The matrix layout is the scalar CSR of a 3x3-block vertex graph, stored so that the three
 * scalar rows of block row r are contiguous: block row r with nb blocks starts at 9*bptr[r];
 * scalar row 3r+i holds, for each block k of the row, the columns 3*bcol[k]+j (j = 0,1,2).
 * bpos[e][a][b] (int32: half the memory of int64, and a rank never holds 2^31 blocks) is the
 * index (into bcol) of the block coupling element vertices a and b, so each element entry lands
 * at a position computed with no search. */
#include <stdint.h>

void petsoft_scatter_add_matrix(int64_t ne, int32_t npe, const int64_t *conn, const int32_t *bpos,
                                const int64_t *bptr, const double *ke, double *vals) {
  const int64_t n = 3 * (int64_t)npe;
  for (int64_t e = 0; e < ne; ++e) {
    const int64_t *ce = conn + e * npe;
    const int32_t *pe = bpos + e * npe * npe;
    const double *k = ke + e * n * n;
    for (int32_t a = 0; a < npe; ++a) {
      const int64_t r = ce[a];
      const int64_t row0 = bptr[r];
      const int64_t stride = 3 * (bptr[r + 1] - row0);
      for (int32_t b = 0; b < npe; ++b) {
        double *dst = vals + 9 * row0 + 3 * (pe[a * npe + b] - row0);
        const double *src = k + (3 * a) * n + 3 * b;
        for (int i = 0; i < 3; ++i) {
          dst[i * stride + 0] += src[i * n + 0];
          dst[i * stride + 1] += src[i * n + 1];
          dst[i * stride + 2] += src[i * n + 2];
        }
      }
    }
  }
}

void petsoft_scatter_add_vector(int64_t ne, int32_t npe, const int64_t *conn, const double *fe,
                                double *out) {
  for (int64_t e = 0; e < ne; ++e) {
    for (int32_t a = 0; a < npe; ++a) {
      const int64_t r = 3 * conn[e * npe + a];
      const double *src = fe + (e * npe + a) * 3;
      out[r] += src[0];
      out[r + 1] += src[1];
      out[r + 2] += src[2];
    }
  }
}
