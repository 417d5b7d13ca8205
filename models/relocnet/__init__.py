"""Training, export and quantisation of relocd's relocalisation networks."""
