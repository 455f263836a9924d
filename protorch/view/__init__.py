"""The live browser viewer of a trained ``point_particle`` or ``arm_reach`` run:
``python -m protorch.view [RUN_DIR]`` or ``protorch view [RUN_DIR]`` (needs ``pip install -e
".[view]"``).

:mod:`~protorch.view.scene` (what is drawn, as plain functions of an environment vector),
:mod:`~protorch.view.live` (the moving-environment controllers one step at a time),
:mod:`~protorch.view.draw` and :mod:`~protorch.view.server` (the viser edge; viser is imported
lazily there), :mod:`~protorch.view.__main__` (the command line).

The teach page (``python -m protorch.view --teach TASK``, docs/teach.md):
:mod:`~protorch.view.teach_tasks` (a task's file format and checks, the arm's IK hand),
:mod:`~protorch.view.teach` (the session: resample, check, keep, continue a folder) and
:mod:`~protorch.view.teach_server` (its viser edge).
"""
