"""Scenario variations: one recorded drive into many labelled variants (camera shifts, lane changes, cars drawn
from a library, parked or moving, placed on the reconstructed road). docs/design.md §16.

``spec`` (what to vary, ``scpainter.variation/1``), ``road`` (the road found headless: RANSAC planes per tile,
occupancy above them), ``library`` (the cars to draw from), ``placement`` (footprints and the rejection rules),
``variants`` (the variants written as job folders, a list for ``batch`` and a manifest). numpy only.
"""
