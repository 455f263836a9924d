"""The command-line edges: the Hydra app (:mod:`.main`) and the sweep report (:mod:`.report`).

The only place in protorch that imports Hydra; everything here calls plain library functions.
"""
