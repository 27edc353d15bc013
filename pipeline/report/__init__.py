"""Figures and the self-contained HTML report: ``build.build(root, vehicle, params)``; shell: stages/report.py."""
