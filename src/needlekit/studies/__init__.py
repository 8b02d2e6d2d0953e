"""Studies: whole jobs that run many plans and write their files (tables, plans, reports)."""
