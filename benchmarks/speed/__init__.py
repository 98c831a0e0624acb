"""What things cost: update, acting and collection speed, CPU and GPU throughput, the
projected cost of budgets (``python -m benchmarks.speed.<name>``)."""
