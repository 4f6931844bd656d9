"""Rules the experiments measure against, which the service does not offer."""
