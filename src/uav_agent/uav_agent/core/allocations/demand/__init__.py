"""The demand allocation (`allocation: demand`, docs/allocation.md): its rules (allocation.py), its relay chains
(chain.py), its roles (layout.py) and their keys (keys.py), its vacated and short roles (vacancy.py), its
memory and gossip (memory.py)."""
from .allocation import Demand

__all__ = ['Demand']
