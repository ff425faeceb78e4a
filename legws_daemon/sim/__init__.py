"""The paper's simulation protocol (method.md §8) on the deployed shared-autonomy loop:
``legws eval``."""
