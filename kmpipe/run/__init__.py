"""`kmpipe run`: a product line as a graph of cached tasks on an in-process, process-pool or Dask executor."""
