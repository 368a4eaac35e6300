"""The benchmark harness: ``fxc benchmark`` runs every registered law (and learned policies) on a suite of
seeded cases and reports deadline errors, tables and figures (docs: benchmark.md).

:mod:`.suite` (cases and contenders), :mod:`.jobs` and :mod:`.ray_jobs` (one batch per job, locally or on
Ray), :mod:`.benchmark` (the command), :mod:`.report`, :mod:`.figures`, :mod:`.dropout` and
:mod:`.resolution` (what is written from the results), :mod:`.filtering_goals` and
:mod:`.graph_agnostic_goals` (two laws' goal tables).
"""
