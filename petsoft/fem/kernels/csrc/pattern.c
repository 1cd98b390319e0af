/* The 3x3-block sparsity pattern of element sets over a vertex graph, and where each element
 * block lands in it (see scatter.c for the value layout).
 *
 * Row r of the block pattern holds every vertex that shares an element with r. It is built from
 * the vertex -> element incidence (a counting sort), with a marker array to drop repeats, so the
 * cost is linear in the element-vertex pairs; rows are then sorted (they hold tens of entries).
 * Element sets may have different numbers of vertices (tetrahedra, springs, contact pairs) and
 * share the pattern. Only the rows listed in `rows` are built (all local vertices for the
 * local pattern; the owned vertices of the whole mesh for a parallel matrix's preallocation).
 *
 * Memory: besides the outputs, the incidence (one int64 per element-vertex pair), one or two
 * int64 per vertex, and the rows themselves until they are copied out. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
  int64_t *ptr; /* nv + 1 */
  int64_t *elt; /* global element index (offset of its set + index in the set) */
} incidence_t;

static int incidence(int64_t nv, int32_t nsets, const int64_t *ne, const int32_t *npe,
                     const int64_t *const *conn, incidence_t *inc) {
  int64_t pairs = 0;
  for (int32_t s = 0; s < nsets; ++s) pairs += ne[s] * npe[s];
  inc->ptr = calloc((size_t)nv + 1, sizeof(int64_t));
  inc->elt = malloc((size_t)(pairs > 0 ? pairs : 1) * sizeof(int64_t));
  if (!inc->ptr || !inc->elt) return -1;
  for (int32_t s = 0; s < nsets; ++s)
    for (int64_t k = 0; k < ne[s] * npe[s]; ++k) inc->ptr[conn[s][k] + 1]++;
  for (int64_t v = 0; v < nv; ++v) inc->ptr[v + 1] += inc->ptr[v];
  int64_t *fill = malloc((size_t)(nv > 0 ? nv : 1) * sizeof(int64_t));
  if (!fill) return -1;
  memcpy(fill, inc->ptr, (size_t)nv * sizeof(int64_t));
  int64_t offset = 0;
  for (int32_t s = 0; s < nsets; ++s) {
    for (int64_t e = 0; e < ne[s]; ++e)
      for (int32_t a = 0; a < npe[s]; ++a) inc->elt[fill[conn[s][e * npe[s] + a]]++] = offset + e;
    offset += ne[s];
  }
  free(fill);
  return 0;
}

/* The set and the index within it of global element g (sets are few: a linear scan). */
static void locate(int64_t g, int32_t nsets, const int64_t *ne, int32_t *set, int64_t *e) {
  int32_t s = 0;
  while (s < nsets - 1 && g >= ne[s]) g -= ne[s++];
  *set = s;
  *e = g;
}

static int cmp_i64(const void *a, const void *b) {
  const int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
  return (x > y) - (x < y);
}

/* Sort a row: insertion sort for the usual tens of entries (qsort's calls through a comparison
 * function took most of the fill's time), qsort for long rows (a contact pair's, a spring hub's). */
static void sort_row(int64_t *row, int64_t n) {
  if (n > 64) {
    qsort(row, (size_t)n, sizeof(int64_t), cmp_i64);
    return;
  }
  for (int64_t i = 1; i < n; ++i) {
    const int64_t v = row[i];
    int64_t j = i - 1;
    while (j >= 0 && row[j] > v) {
      row[j + 1] = row[j];
      --j;
    }
    row[j + 1] = v;
  }
}

/* Visit the distinct neighbours of vertex r: count them (out == NULL) or write them. */
static int64_t neighbours(int64_t r, int32_t nsets, const int64_t *ne, const int32_t *npe,
                          const int64_t *const *conn, const incidence_t *inc, int64_t *marker,
                          int64_t *out) {
  int64_t count = 0;
  for (int64_t k = inc->ptr[r]; k < inc->ptr[r + 1]; ++k) {
    int32_t s;
    int64_t e;
    locate(inc->elt[k], nsets, ne, &s, &e);
    const int64_t *ce = conn[s] + e * npe[s];
    for (int32_t b = 0; b < npe[s]; ++b) {
      const int64_t c = ce[b];
      if (marker[c] != r) {
        marker[c] = r;
        if (out) out[count] = c;
        ++count;
      }
    }
  }
  return count;
}

/* The rows in one pass over the incidence: each row's distinct neighbours go to a growing buffer
 * (sorted; with `pos`, where each element block lands), bptr[i+1] - bptr[i] their count. Two
 * passes (count, then fill) built the incidence twice and visited every neighbour twice: 0.2 s
 * of a 0.6 s pattern at 1M tets. The buffer is handed back as a pattern_rows_t; the caller,
 * having read the size from bptr, copies it out with petsoft_pattern_take (which frees it).
 *
 * `pos` (one (ne, npe, npe) int32 array per set; only when rows = 0..nv-1 in order): the index
 * into bcol of conn[b] in row conn[a], read from a per-row map of column -> index (the marker
 * array's twin), no search. Returns NULL with *status 1 when an allocation failed, 2 when the
 * rows hold more blocks than an int32 position can name. */
typedef struct {
  int64_t *col;
  int64_t size;
} pattern_rows_t;

void *petsoft_pattern_build(int64_t nv, int32_t nsets, const int64_t *ne, const int32_t *npe,
                            const int64_t *const *conn, int64_t nrows, const int64_t *rows,
                            int64_t *bptr, int32_t *const *pos, int32_t *status) {
  incidence_t inc = {0, 0};
  *status = 1;
  int32_t widest = 1;
  for (int32_t s = 0; s < nsets; ++s)
    if (npe[s] > widest) widest = npe[s];
  int64_t *marker = malloc((size_t)(nv > 0 ? nv : 1) * sizeof(int64_t));
  int64_t *where = pos ? malloc((size_t)(nv > 0 ? nv : 1) * sizeof(int64_t)) : NULL;
  /* a first guess of the size: 16 neighbours a row (a 4-node tetrahedral mesh has ~15) */
  int64_t capacity = 16 * (nrows > 0 ? nrows : 1);
  pattern_rows_t *out = malloc(sizeof(pattern_rows_t));
  int64_t *col = malloc((size_t)capacity * sizeof(int64_t));
  if (!marker || (pos && !where) || !out || !col || incidence(nv, nsets, ne, npe, conn, &inc))
    goto fail;
  for (int64_t v = 0; v < nv; ++v) marker[v] = -1;
  bptr[0] = 0;
  for (int64_t i = 0; i < nrows; ++i) {
    const int64_t r = rows[i];
    const int64_t most = (inc.ptr[r + 1] - inc.ptr[r]) * widest + 1;
    if (bptr[i] + most > capacity) {
      capacity = 2 * capacity > bptr[i] + most ? 2 * capacity : bptr[i] + most;
      int64_t *grown = realloc(col, (size_t)capacity * sizeof(int64_t));
      if (!grown) goto fail;
      col = grown;
    }
    int64_t *row = col + bptr[i];
    const int64_t n = neighbours(r, nsets, ne, npe, conn, &inc, marker, row);
    sort_row(row, n);
    bptr[i + 1] = bptr[i] + n;
    if (!pos) continue;
    if (bptr[i + 1] > INT32_MAX) {
      *status = 2;
      goto fail;
    }
    for (int64_t k = 0; k < n; ++k) where[row[k]] = bptr[i] + k;
    for (int64_t k = inc.ptr[r]; k < inc.ptr[r + 1]; ++k) {
      int32_t s;
      int64_t e;
      locate(inc.elt[k], nsets, ne, &s, &e);
      const int64_t *ce = conn[s] + e * npe[s];
      for (int32_t a = 0; a < npe[s]; ++a) {
        if (ce[a] != r) continue; /* (a vertex twice in one element: each a gets its row) */
        int32_t *pe = pos[s] + (e * npe[s] + a) * npe[s];
        for (int32_t b = 0; b < npe[s]; ++b) pe[b] = (int32_t)where[ce[b]];
      }
    }
  }
  free(marker); free(where); free(inc.ptr); free(inc.elt);
  out->col = col;
  out->size = bptr[nrows];
  *status = 0;
  return out;
fail: /* *status says why (1: an allocation, 2: too many blocks) */
  free(marker); free(where); free(out); free(col); free(inc.ptr); free(inc.elt);
  return NULL;
}

/* Copy the rows built by petsoft_pattern_build into bcol (bptr[nrows] entries) and free them;
 * with bcol NULL only free them. */
void petsoft_pattern_take(void *built, int64_t *bcol) {
  pattern_rows_t *rows = built;
  if (!rows) return;
  if (bcol && rows->size > 0) memcpy(bcol, rows->col, (size_t)rows->size * sizeof(int64_t));
  free(rows->col);
  free(rows);
}

/* The scalar CSR of the block pattern in scatter.c's layout: the three scalar rows of block row
 * r are contiguous, row 3r+i holds columns 3*bcol[k]+j for each block k of the row. Column
 * indices are mapped through `colmap` (block column -> first scalar column) when given, else
 * 3*bcol. */
#define SCALAR_CSR(NAME, INT)                                                                  \
  void NAME(int64_t nrows, const int64_t *bptr, const int64_t *bcol, const int64_t *colmap,     \
            INT *indptr, INT *indices) {                                                          \
    for (int64_t r = 0; r < nrows; ++r) {                                                         \
      const int64_t nb = bptr[r + 1] - bptr[r];                                                   \
      for (int i = 0; i < 3; ++i) {                                                               \
        const int64_t start = 9 * bptr[r] + 3 * nb * i;                                           \
        indptr[3 * r + i] = (INT)start;                                                           \
        for (int64_t k = 0; k < nb; ++k) {                                                        \
          const int64_t c = bptr[r] + k;                                                          \
          const int64_t col = colmap ? colmap[bcol[c]] : 3 * bcol[c];                             \
          indices[start + 3 * k + 0] = (INT)col;                                                  \
          indices[start + 3 * k + 1] = (INT)(col + 1);                                            \
          indices[start + 3 * k + 2] = (INT)(col + 2);                                            \
        }                                                                                         \
      }                                                                                           \
    }                                                                                             \
    indptr[3 * nrows] = (INT)(9 * bptr[nrows]);                                                   \
  }

/* 32-bit (PETSc's default index type) and 64-bit outputs. */
SCALAR_CSR(petsoft_pattern_scalar32, int32_t)
SCALAR_CSR(petsoft_pattern_scalar64, int64_t)
