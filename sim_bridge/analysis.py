"""What happened in a run, from its MCAP log alone: now one module per concept.

:mod:`sim_bridge.log_file` (reading, recovery, repair), :mod:`sim_bridge.log_reader`
(the decoded run), :mod:`sim_bridge.log_columns` (poses and commands as columns),
:mod:`sim_bridge.log_phases` (phases), :mod:`sim_bridge.log_report` (the report),
:mod:`sim_bridge.report_text` (tables), :mod:`sim_bridge.counterfactual`.
"""

from sim_bridge.log_report import report_log  # noqa: F401  # re-export: moved to sim_bridge.log_report
