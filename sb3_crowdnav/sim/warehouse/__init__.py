"""The warehouse world on the ground floor: layouts, routes, pickers and the simulator of ``CrowdNavWarehouse-v0``."""

from sb3_crowdnav.sim.warehouse.layout import LayoutRanges, Roadmap, WarehouseLayout, generate_layout

__all__ = ["LayoutRanges", "Roadmap", "WarehouseLayout", "generate_layout"]
