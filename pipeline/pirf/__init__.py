"""PIRF-nav2: loop closure and localization with position-invariant robust features (issue 6)."""
