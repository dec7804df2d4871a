"""Volumetric-heatmap stacked-hourglass CNN (thesis ch. 2.4.1). Not built yet: see issue 5."""
