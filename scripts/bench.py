#!/usr/bin/env python3
"""Benchmark docker-ros image builds: `python scripts/bench.py --help`. The bench itself is the
package beside this file (scripts/bench/: workspace generator, scenarios, report)."""

import sys

from bench.cli import main

if __name__ == "__main__":
    sys.exit(main())
