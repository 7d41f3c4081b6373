"""The control law and its decisions: sliding-mode law S3, formation field S4, limit-cycle field
and gain design S6, encounters S7, automaton S8, arbiter, graph rewiring S9, the one-robot
controller, the S10 estimator, the controlled stop. Imports core/ base and model/ only.
"""
