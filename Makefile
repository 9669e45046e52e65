# Bootstrap is implicit: every target goes through ./uav-flock, which sets up .venv and ros2_ws once.
.PHONY: run test bootstrap clean distclean

run:
	./uav-flock run

test:
	./uav-flock test

bootstrap:
	./uav-flock bootstrap

clean:
	rm -rf ros2_ws/build ros2_ws/install ros2_ws/log ros2_ws/colcon.out ros2_ws/.uav-flock-stamp

distclean: clean
	rm -rf .venv
