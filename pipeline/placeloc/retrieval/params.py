"""Retrieval parameters: the one home of their defaults, ranges and meaning."""

from __future__ import annotations

from dataclasses import dataclass

from placeloc.core.params import Params, param


@dataclass(frozen=True)
class RetrievalParams(Params):
    thumbnail: tuple[int, int] = param([64, 32], min=4, help="thumbnail width, height in pixels (the image's own "
                                                             "feature when no descriptors are given)")
    descriptors_reference: str | None = param(None, path=True,
                                              help="descriptors computed elsewhere for the reference images (.npy "
                                                   "matrix, .h5/.hdf5, or a folder of one .npy per image; one row per "
                                                   "image in folder order): used instead of thumbnails")
    descriptors_query: str | None = param(None, path=True, help="the same for the query images")
    distance: str = param("cosine", choices=("cosine", "l2"), help="cosine similarity or Euclidean distance")
    top_k: int = param(20, min=1, help="candidates kept per query (Recall@N up to this N)")
    search: str = param("auto", choices=("auto", "exact", "faiss"),
                        help="exact (numpy, blocks of queries), faiss (a flat faiss index) or auto: faiss from "
                             "faiss_from reference images on")
    faiss_from: int = param(20000, min=1, help="auto search: reference images from which faiss is used")
    block_size: int = param(1024, min=1, affects_result=False,
                            help="queries per block of the exact search (memory, never the result)")
