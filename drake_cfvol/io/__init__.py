"""Records on disk, progress bars, plotting and colours: what every other layer
may use. Imports nothing of the package but ``exceptions``.
"""
