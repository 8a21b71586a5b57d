"""A results folder read back.

The summary table, intervals over seeds, paired differences, figures,
report.md and report.html. It knows nothing about runs.
"""
