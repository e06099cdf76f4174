"""The engine every method runs on: config and parameters, the runner and its stage
context, executors, artifacts, image listing, resource limits and the error types.

Nothing here names a method: methods are found by :mod:`placeloc.core.methods` listing the
package's folders, and everything after localize is chosen by the result contract a method
declares (:mod:`placeloc.evaluation.contracts`).
"""
