"""The labeling studio: a viser app that serves a workspace's edges to annotators' browsers.

``serve.serve`` runs it with the model's predictions and the background trainer beside it.
"""
