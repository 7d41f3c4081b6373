"""The ROS-free closed loop and what surrounds it: simulator, hardware twin, metrics, records,
plots, the live view's scene. Imports base, model/, control/ and scenario/.
"""
