"""skelasm's engine: parts, skeletal density descriptors, Fourier correlation, simulation.

Nothing in this package imports Qt, VTK or the application; it runs headless.
"""

__version__ = "0.1.0"
