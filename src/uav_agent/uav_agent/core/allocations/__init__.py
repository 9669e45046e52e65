"""The allocations a scenario may choose (policies.ALLOCATIONS): each in its own module or package, with its
own memory and what it adds to a MAP's state message (docs/design.md, "Adding an allocation")."""
