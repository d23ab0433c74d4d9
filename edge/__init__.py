"""edge-ips: optical indoor positioning for small robot fleets."""
