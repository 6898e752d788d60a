"""The live view: a Foxglove WebSocket server fed from the graph or the offline loop."""
