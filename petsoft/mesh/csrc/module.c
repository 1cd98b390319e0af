/* A Python extension module with no Python-visible functions: it exists so that the import
 * system can locate this shared library; petsoft.mesh.ordering then loads the C functions in it
 * with ctypes. (The mesh layer has its own library: it sits below petsoft.fem, whose kernels
 * are the other one.) */
#include <Python.h>

static struct PyModuleDef cmesh_module = {
    PyModuleDef_HEAD_INIT, "_cmesh", "petsoft compiled mesh orderings (loaded via ctypes)",
    -1, NULL, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__cmesh(void) { return PyModule_Create(&cmesh_module); }
