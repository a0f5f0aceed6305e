"""Batch over many logs on Dask: the client (batch), the cluster, one log's task, the workers' warm-up, URLs."""
