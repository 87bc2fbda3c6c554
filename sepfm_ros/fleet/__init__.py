"""The fleet audit's parts that need no ROS and no bag reader: finding bags, naming rigs,
splitting long bags into time slices, the audit's records and its CSV ledger (resume, one row per
bag), the engine (Dask distributed, local or a cluster by address) and the fleet report.

The bag-reading side (a bag's inputs and rig, one slice's pairs through the node's answer path)
is :mod:`sepfm_ros.ros.offline.audit_slices`; the command is :mod:`sepfm_ros.ros.commands.audit`.
"""
