import os
import sys

sys.path.insert(0, os.path.dirname(__file__))
# the notebook generators import their shared helper, notebooks/nbbuild.py
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "notebooks"))
