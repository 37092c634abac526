"""Device ports (``typing.Protocol``), their real adapters, and ``drivers/sim`` with simulated devices."""
