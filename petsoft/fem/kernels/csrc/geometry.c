/* Reference geometry of linear tetrahedra: shape-function gradients, 6 x signed volume and the
 * longest edge, one pass over the elements (the numpy version made a dozen (n, 3) temporaries:
 * 1.1 s of a 2.9 s set-up at 1M tets; this pass takes 0.06 s). The rows of D^-1 as cross
 * products of the edge vectors over det D, as the closed form in petsoft/fem/kernels/tet.py
 * says; it agrees with the numpy evaluation to round-off (4e-14 on gradients of size 55). */
#include <stdint.h>

static double dot3(const double *a, const double *b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double *a, const double *b, double *out) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

/* One tetrahedron: x (4 x 3 coordinates) -> g (4 x 3 gradients), *det, *longest2. */
static void tet(const double *x, double *g, double *det, double *longest2) {
  double ed[6][3];
  for (int i = 0; i < 3; ++i) {
    ed[0][i] = x[3 + i] - x[i];
    ed[1][i] = x[6 + i] - x[i];
    ed[2][i] = x[9 + i] - x[i];
  }
  for (int i = 0; i < 3; ++i) {
    ed[3][i] = ed[1][i] - ed[0][i];
    ed[4][i] = ed[2][i] - ed[0][i];
    ed[5][i] = ed[2][i] - ed[1][i];
  }
  cross3(ed[1], ed[2], g + 3);
  cross3(ed[2], ed[0], g + 6);
  cross3(ed[0], ed[1], g + 9);
  const double d = dot3(ed[0], g + 3);
  double l2 = 0.0;
  for (int k = 0; k < 6; ++k) {
    const double s = dot3(ed[k], ed[k]);
    if (s > l2) l2 = s;
  }
  *det = d;
  *longest2 = l2;
  if (d != 0.0) {
    const double inv = 1.0 / d;
    for (int k = 3; k < 12; ++k) g[k] *= inv;
  }
  for (int i = 0; i < 3; ++i) g[i] = -((g[3 + i] + g[6 + i]) + g[9 + i]);
}

/* Tetrahedra `cells` (n, 4) of `points` (nv, 3), gathered here: no (n, 4, 3) coordinate array
 * (96 MB at 1M tets, most of its cost page faults). Out: dN (n, 4, 3) shape gradients (left
 * unscaled, i.e. times det, when det is 0), det (n,) = 6 x signed volume, longest2 (n,) the
 * longest squared edge. */
void petsoft_tet_geometry_indexed(int64_t n, const double *points, const int64_t *cells,
                                  double *dN, double *det, double *longest2) {
  for (int64_t e = 0; e < n; ++e) {
    double x[12];
    for (int a = 0; a < 4; ++a)
      for (int i = 0; i < 3; ++i) x[3 * a + i] = points[3 * cells[4 * e + a] + i];
    tet(x, dN + 12 * e, det + e, longest2 + e);
  }
}
