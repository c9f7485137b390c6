"""Readers and writers of the user's files that are not logger logs.

Vehicle files, cycle files, fleet scenarios, trip manifests (:mod:`cevm.io.manifest`),
calibrated vehicle files and plots: the edges where cevm's pure core (:mod:`cevm.core`)
meets the file system. Logger exports are read by the ingest pipeline
(:mod:`cevm.ingest`).

The readers are re-exported here: ``from cevm.io import read_cycle_csv``.
"""

from cevm.io.cycles import CycleFormat, read_cycle_csv, read_cycles
from cevm.io.toml import read_toml
from cevm.io.vehicles import load_vehicle, load_vehicles

__all__ = ["CycleFormat", "load_vehicle", "load_vehicles", "read_cycle_csv", "read_cycles", "read_toml"]
