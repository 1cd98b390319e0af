"""Element kernels: pure functions over arrays of elements (numpy reference and compiled C)."""
