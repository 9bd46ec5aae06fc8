"""The file formats kmpipe reads and writes: safe file access and atomic writes, the TOML input layer, spectral CSV,
sample manifests and samples, materials, render scenes, product-line recipes and albedo textures."""
