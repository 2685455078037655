"""The former numpy engine, kept as an independent oracle for the compiled kernels (tests only)."""
