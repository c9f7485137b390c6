"""cevm: computationally efficient vehicle energy models.

The physics core (:mod:`cevm.core.cycle`, :mod:`cevm.core.model`, :mod:`cevm.core.vehicle`) is pure:
arrays and small frozen dataclasses in, arrays out, no I/O. Reading files, the store and
the command line live at the edges (:mod:`cevm.io.cycles`, :mod:`cevm.cli`, ...).
"""

__version__ = "0.1.0"
