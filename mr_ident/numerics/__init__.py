"""Numerics: the lowest layer (pure numpy/scipy, no I/O, no ROS).

Lifting, the local polynomial method, the identification methods (a table, one function
per method), the lifted loop, the PFG, LTI systems, the loop model, simulation and
excitation signals, the one container of loop signals and the frozen result types.
Imports only :mod:`mr_ident.errors`.
"""
