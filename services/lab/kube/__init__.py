"""The lab on Kubernetes: a lab file's host as manifests, and arenas as workloads on request.

manifests.py turns one host of a lab file into Kubernetes objects (or into the
pods ``podman kube play`` runs); arenas.py creates and deletes an arena's
workload through the Kubernetes API when ``wart arena new`` asks a lab that
runs in a cluster.
"""
