"""A user's side of the lab: LabClient (login, directory, rooms, mail), the
errors a user meets, and the calls on agent contexts, hosts and the registry
that commands, the viewer and services acting as a user make."""
