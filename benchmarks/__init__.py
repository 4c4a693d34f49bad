"""softsim's benchmark suite: ``python -m benchmarks [--quick] [-o DIR]`` (see ``__main__``)."""
