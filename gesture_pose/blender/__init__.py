"""The Blender side of gesture_pose: readers, writers, operators, panels, properties.

The only package that imports bpy. It reads Blender state once into core dataclasses,
calls the core, writes the result back and turns core errors into reports.
"""
