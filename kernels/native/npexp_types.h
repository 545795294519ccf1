// The 16-lane types (v16f, v16i) that npexp16.h works on (kernels/_npexp.py).

    typedef float v16f __attribute__((ext_vector_type(16)));
    typedef int v16i __attribute__((ext_vector_type(16)));
