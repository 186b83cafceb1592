"""The paper's baselines as method definitions on the shared core: vanilla SAC and SAC+HER+PER."""
