"""Reading and writing: MCAP logs and bags, decoding, the spec, serialization into
episodes, slicing, the Parquet library file, atomic files."""
