"""What a flight means: metrics and coverage, plots, viewing logs, reports."""
