/* A Python extension module with no Python-visible functions: it exists so that the import
 * system can locate this shared library; petsoft.kernels.compiled then loads the C kernels in
 * it with ctypes. */
#include <Python.h>

static struct PyModuleDef ckernels_module = {
    PyModuleDef_HEAD_INIT, "_ckernels", "petsoft compiled element kernels (loaded via ctypes)",
    -1, NULL, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__ckernels(void) { return PyModule_Create(&ckernels_module); }
