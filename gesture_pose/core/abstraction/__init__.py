"""Sketch abstractions and draw-over posing (Hahn et al., SCA 2015).

A sketch abstraction is a set of rigged curves; the rig parameters are optimized so that the
abstraction's projection matches newly drawn strokes (ICP with a bounded Gauss-Newton QP).
"""
