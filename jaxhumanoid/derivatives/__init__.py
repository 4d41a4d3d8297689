"""Sparse derivatives from JAX: sparsity patterns, graph colouring, compressed evaluation."""
