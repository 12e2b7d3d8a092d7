"""The pipeline's part of each region model: its summary, result files and printed line."""
