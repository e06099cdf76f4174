"""UMap: localize camera images against line images rendered from a 3-D wireframe pre-map,
with the Consistency Adjustment (CA) of seed 001_5b098ba37914637b.txt."""
