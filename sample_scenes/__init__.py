"""Sample scenes built in code (builders.py) and the script that saves them (make_scenes.py)."""
