#!/usr/bin/env bash
# Installs every system dependency of normal_fusion from Debian 12's own packages.
# Idempotent: when every package is already present it returns in well under a second.
set -euo pipefail
export PATH=/usr/bin:/bin:/usr/sbin:/sbin:$PATH

PACKAGES=(
  build-essential cmake python3 pkg-config
  catkin libroscpp-dev libnodeletlib-dev libnodeletlib-tools libimage-transport-dev
  libmessage-filters-dev libcv-bridge-dev libsensor-msgs-dev libstd-msgs-dev
  ros-std-msgs ros-sensor-msgs ros-message-generation ros-message-runtime pluginlib-dev
  libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
  librostest-dev python3-rostest python3-roslaunch python3-rosmaster rosout
  python3-rostopic python3-rosbag python3-sensor-msgs python3-rosnode python3-rosparam
  python3-rosservice libgtest-dev libgmock-dev libopencv-dev libopencv-contrib-dev
  libbenchmark-dev libyaml-cpp-dev
  librosbag-dev libtf2-ros-dev libdiagnostic-updater-dev ros-diagnostic-msgs
  python3-diagnostic-msgs rosbash python3-nodelet
  # The platform checks of scripts/run_tests.sh: other compilers, catkin_lint.
  g++-11 clang-14 libomp-14-dev catkin-lint
)
# Optional data: the ViSP image set (real and synthetic RGB-D sequences; GPL-2 data) and
# opencv-doc (Middlebury Aloe, the real stereo pair of evaluate), both
# installed at run time and never copied into the repository.
OPTIONAL_PACKAGES=(visp-images-data opencv-doc)

missing=()
for pkg in "${PACKAGES[@]}" "${OPTIONAL_PACKAGES[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$pkg")
  fi
done
[ ${#missing[@]} -eq 0 ] && exit 0

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "normal_fusion setup: installing ${#missing[@]} missing Debian packages: ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
required_missing=()
for pkg in "${missing[@]}"; do
  case " ${OPTIONAL_PACKAGES[*]} " in *" $pkg "*) ;; *) required_missing+=("$pkg") ;; esac
done
if [ ${#required_missing[@]} -gt 0 ]; then
  $SUDO apt-get install -y -qq --no-install-recommends "${required_missing[@]}" >/dev/null
fi
for pkg in "${OPTIONAL_PACKAGES[@]}"; do
  case " ${missing[*]} " in
    *" $pkg "*)
      $SUDO apt-get install -y -qq --no-install-recommends "$pkg" >/dev/null ||
        echo "normal_fusion setup: optional package $pkg could not be installed; continuing without it" ;;
  esac
done
