"""Single-image retrieval: each query's nearest reference images (the place-recognition baseline)."""
