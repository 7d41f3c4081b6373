"""The plant and its world (S1, S2, S6.1): robot dynamics, disturbance, obstacles and their motion,
reference paths, ellipse geometry. Imports only the core's base modules.
"""
