"""What the maze and the driving benchmark share: the episode runner (``episode``), the loss
terms and the SGD loop (``learn``), the network parts (``nn``), the method parameters with one
default each (``params``) and the device mesh (``devices``). All depend on JAX alone (no other
igdrivsim module), so any environment can build on them."""
