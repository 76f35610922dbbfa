"""MaRINeR core: reference-based render enhancement (standalone PyTorch package)."""
