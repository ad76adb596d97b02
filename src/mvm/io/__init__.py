"""Readers and writers, one module per format. Math modules never import from here."""
