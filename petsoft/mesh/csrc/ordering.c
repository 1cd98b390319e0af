/* Morton (Z-order) keys of cell centroids, in two passes over the cells and no temporaries.
 *
 * The same numbers as petsoft.mesh.ordering's numpy reference, morton_keys(cell_centroids(...)):
 * a centroid is the sum of the cell's vertices in order divided by their count, quantised on the
 * centroids' bounding box ((c - lo) / (largest extent) * (2^21 - 1), rounded down) and its three
 * 21-bit coordinates interleaved. The numpy version made a dozen (n, 3) and (n,) temporaries:
 * 0.3 s of the distribution's 0.5 s at 1M tets. */
#include <float.h>
#include <math.h>
#include <stdint.h>

#define BITS 21

/* Insert two zero bits between the low 21 bits of v (for 3D interleaving). */
static uint64_t spread_bits(uint64_t v) {
  v &= 0x1FFFFFull;
  v = (v | (v << 32)) & 0x1F00000000FFFFull;
  v = (v | (v << 16)) & 0x1F0000FF0000FFull;
  v = (v | (v << 8)) & 0x100F00F00F00F00Full;
  v = (v | (v << 4)) & 0x10C30C30C30C30C3ull;
  v = (v | (v << 2)) & 0x1249249249249249ull;
  return v;
}

/* The centroid c of a cell: the mean of its first npe vertices, summed in order. */
static void centroid(const double *points, const int64_t *cell, int32_t npe, double *c) {
  const double *p = points + 3 * cell[0];
  c[0] = p[0];
  c[1] = p[1];
  c[2] = p[2];
  for (int32_t k = 1; k < npe; ++k) {
    p = points + 3 * cell[k];
    c[0] += p[0];
    c[1] += p[1];
    c[2] += p[2];
  }
  for (int i = 0; i < 3; ++i) c[i] /= (double)npe;
}

void petsoft_cell_morton_keys(int64_t ncells, int32_t npe, int64_t stride, const int64_t *cells,
                              const double *points, uint64_t *keys) {
  if (ncells <= 0) return;
  double lo[3], hi[3], c[3];
  centroid(points, cells, npe, lo);
  for (int i = 0; i < 3; ++i) hi[i] = lo[i];
  for (int64_t e = 1; e < ncells; ++e) {
    centroid(points, cells + e * stride, npe, c);
    for (int i = 0; i < 3; ++i) {
      if (c[i] < lo[i]) lo[i] = c[i];
      if (c[i] > hi[i]) hi[i] = c[i];
    }
  }
  double extent = DBL_MIN; /* numpy: max over axes of max(hi - lo, tiny) */
  for (int i = 0; i < 3; ++i) {
    const double d = hi[i] - lo[i] > DBL_MIN ? hi[i] - lo[i] : DBL_MIN;
    if (d > extent) extent = d;
  }
  const double top = (double)((1 << BITS) - 1);
  for (int64_t e = 0; e < ncells; ++e) {
    centroid(points, cells + e * stride, npe, c);
    uint64_t key = 0;
    for (int i = 0; i < 3; ++i) {
      const int64_t q = (int64_t)floor((c[i] - lo[i]) / extent * top);
      key |= spread_bits((uint64_t)q) << i;
    }
    keys[e] = key;
  }
}
