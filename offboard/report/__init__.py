"""Reports: metrics, figures and report.html for sim / fly / demo, replay, compare and sweep runs.

Written after a run; the flight loop never loads these while it flies.
"""
