"""abyssal.runtime: NumPy/SciPy numerics on top of the compiled generated code."""
