"""PIRF-nav2: loop closure and localization with position-invariant robust features
(H. Sasaki and T. Hamagami, "Construction of feature space for speeding up self-localization
using time series omnidirectional images"; PIRF-nav2 by A. Kawewong, N. Tongprasit and
O. Hasegawa)."""
