"""A checked plan executed.

The comparison, the per-process session, the harness of one run, the rows it
writes, executors, isolation and writing a recording.
"""
