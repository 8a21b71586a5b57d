"""What is seen of the truth.

The observation kinds (markers, force, a depth camera's cloud), occlusion,
and the observed model an estimator is handed.
"""
