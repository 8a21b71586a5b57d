"""Commands built on the models: ``idbench calibrate`` (the beam's effective-E map)."""
