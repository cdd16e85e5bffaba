import sys
from pathlib import Path

# The brute-force twin (reference_renderer.py) lives beside the tests.
sys.path.insert(0, str(Path(__file__).parent))
