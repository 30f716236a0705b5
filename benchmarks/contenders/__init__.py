"""Other simulators running the library's scenes, for the benchmark suite's comparisons."""
