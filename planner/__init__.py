"""planner: pure algorithms of the RTNUA problem.

Owns: the problem definition and presets (``problem``), shared geometry (``geometry``), the
semi-Steiner task tree (``steiner``), PhiIREMAN's potential-field descent (``phireman``), the
asynchronous knowledge model (``knowledge``), the information models a planner plans with, central
or message passing (``info``), paper length units (``units``), the baselines (``mccst``,
``dccrs``), the metrics (``metrics``) and the planner registry (``methods``).

Must not import: any other package of this project, sockets, asyncio, time, YAML, pymavlink,
plotting, or the global random state. Time and randomness are always arguments.
"""
