"""Stick figures in an environment (Lin, Igarashi, Mitani, Liao and He, TVCG 2012).

The user draws a 2D stick figure; :mod:`.graph` turns the strokes into a tree matched to the
character's major joints (:mod:`.figure`), :mod:`.environment` finds where the character
sits, :mod:`.objective` scores 3D poses (Eqs. 4-11), :mod:`.genetic` and :mod:`.refine`
search them and :mod:`.solve` ties everything together.
"""
