"""Tool-workpiece engagement: the stock as a Z-map swept by the tool.

Layer: physics below the simulator, the calibration and the optimizer (it imports only
:mod:`cnctwin.machine` and :mod:`cnctwin.exceptions`). :class:`Stock` describes the raw part,
:class:`ZMap` holds its heights on a grid and :meth:`ZMap.sweep` moves a tool along a path,
giving per control cycle the engagement (entry and exit angle, axial depth, removed volume)
that the mechanistic milling model needs, and removing the material.
"""

from cnctwin.engagement.stock import Engagement, Stock, ZMap, parse_stock, runs_of

__all__ = ["Engagement", "Stock", "ZMap", "parse_stock", "runs_of"]
