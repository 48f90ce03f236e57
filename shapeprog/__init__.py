"""ShapeAssembly: a language of attached cuboids, its differentiable executor, corpus and metrics."""
