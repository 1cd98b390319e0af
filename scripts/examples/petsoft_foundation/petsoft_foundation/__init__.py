"""A bilinear elastic foundation for petsoft: the term is :mod:`petsoft_foundation.term`."""
