"""Figures and the self-contained HTML report (``build.build(root, vehicle, params)``; stage shell: stages/report.py)."""
