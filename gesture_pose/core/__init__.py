"""Pure numerical core of gesture_pose: numpy, scipy and osqp only.

Nothing here imports Blender. Inputs and results are frozen dataclasses of numpy arrays,
3D data in world space and units, 2D data in pixels (origin bottom-left).
"""
