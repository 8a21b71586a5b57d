"""An estimate judged against the truth.

Shape, transfer and target errors.
"""
