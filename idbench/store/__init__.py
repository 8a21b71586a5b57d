"""What goes to disk.

Result tables, recordings, the output folder's lock, stable hashes and atomic
writes.
"""
