"""The semi-discrete residual r = M a + grad W(q) + D v (+ velocity terms) - f_g, prescribed rows
zeroed, evaluated at given parameters: the function whose parameter derivatives the Taylor tests
check against ``residual_parameter_derivatives``."""


def semi_discrete_residual(s, values, q, v, a):
    """r(q, v, a; p) of system ``s`` after ``s.set_parameters(values)`` (a new vector)."""
    s.set_parameters(values)
    out, w = s.create_vec(), s.create_vec()
    s.internal_gradient(q, out)
    s.M.mult(a, w)
    out.axpy(1.0, w)
    out.axpy(1.0, s.damping_apply(v, w))
    out.axpy(-1.0, s.gravity)
    s.zero_prescribed(out)
    return out
