"""UMap: localization against line images rendered from a wireframe pre-map, with the
Consistency Adjustment (CA) of K. Takahashi, J. Takahashi, T. Kaneko and Y. Tobe,
"Improving pre-map indoor localization by comparing consecutive images"; whole 360 degree
panoramas with the yaw searched (see docs/umap.md)."""
