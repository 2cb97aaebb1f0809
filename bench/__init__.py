"""Benchmarks and the paper's table (run as ``python -m bench.<script>``; never run by pytest)."""
