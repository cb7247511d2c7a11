"""ilcforce's benchmarks (``make bench``, ``python -m benchmarks``): speed figures of the commands a user
runs and of their parts. Not part of the installed package; run from the repository root."""
