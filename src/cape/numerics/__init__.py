"""Numerics beside NumPy: CasADi functions compiled to C and cached (compiled), buffered
calls (buffered), and the interrupt that stops a lap between steps (interrupt)."""
